//! Sparse SE(2) pose-graph optimisation: Levenberg-Marquardt on the 3x3-block normal
//! equations, solved by a sparse block Cholesky factorisation after a minimum-degree
//! (AMD-style) ordering of the nodes; ordering and symbolic factorisation once per
//! optimisation, the numeric factorisation per step. Loop-closure edges may carry a Cauchy
//! kernel (iteratively reweighted), so a wrong closure loses its pull instead of bending
//! the map.
//!
//! Error of an edge `i -> j` with measurement `z` (pose of `j` in the frame of `i`):
//! `e = t2v(z^-1 * (x_i^-1 * x_j))`, Jacobians as in Grisetti et al., "A tutorial on
//! graph-based SLAM" (2010). Node 0 is held fixed (the gauge).

use crate::geometry::{Pose2, wrap_angle};
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use rayon::prelude::*;

/// Graphs with at least this many edges evaluate their cost's terms in parallel (summed in
/// order, so the same bits); smaller ones are not worth the threads.
const PARALLEL_COST_EDGES: usize = 4096;

/// One constraint: `measurement` is node `to`'s pose in the frame of node `from`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    /// Earlier node.
    pub from: usize,
    /// Later node.
    pub to: usize,
    /// `from_T_to`.
    pub measurement: Pose2,
    /// Information matrix (inverse covariance) of the error `(x, y, yaw)`.
    pub information: Matrix3<f64>,
    /// Cauchy kernel width (in units of the whitened error, sqrt of chi^2); `None` = plain
    /// least squares.
    pub robust_width: Option<f64>,
}

impl Edge {
    /// An edge with a diagonal information from standard deviations (m, m, rad).
    pub fn with_sigmas(
        from: usize,
        to: usize,
        measurement: Pose2,
        sigma_xy_m: f64,
        sigma_yaw_rad: f64,
        robust_width: Option<f64>,
    ) -> Edge {
        let ixy = 1.0 / (sigma_xy_m * sigma_xy_m);
        let iyaw = 1.0 / (sigma_yaw_rad * sigma_yaw_rad);
        Edge {
            from,
            to,
            measurement,
            information: Matrix3::from_diagonal(&Vector3::new(ixy, ixy, iyaw)),
            robust_width,
        }
    }
}

/// Nodes and edges.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PoseGraph {
    /// Node poses (world frame); node 0 is fixed.
    pub poses: Vec<Pose2>,
    /// Constraints.
    pub edges: Vec<Edge>,
}

/// Options of one optimisation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OptimizeOptions {
    /// Iteration limit.
    pub max_iterations: usize,
    /// Stop when the relative decrease of the cost falls below this.
    pub relative_tolerance: f64,
}

impl Default for OptimizeOptions {
    fn default() -> Self {
        OptimizeOptions {
            max_iterations: 20,
            relative_tolerance: 1e-6,
        }
    }
}

/// What an optimisation did.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct OptimizeReport {
    /// Iterations (accepted or not).
    pub iterations: usize,
    /// Robust cost before.
    pub initial_cost: f64,
    /// Robust cost after.
    pub final_cost: f64,
}

/// Error, and Jacobians with respect to `x_i` and `x_j`, of one edge; `rz` = `rot(z.yaw_rad)`
/// (the same for every iteration: computed once per optimisation).
fn linearise(
    xi: &Pose2,
    xj: &Pose2,
    z: &Pose2,
    rz: &Matrix2<f64>,
) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>) {
    let (s, c) = xi.yaw_rad.sin_cos();
    let ri = Matrix2::new(c, -s, s, c);
    let dt = Vector2::new(xj.x_m - xi.x_m, xj.y_m - xi.y_m);
    let rzt_rit = rz.transpose() * ri.transpose();
    // The same expressions as `edge_error` (the same bits).
    let et = rz.transpose() * (ri.transpose() * dt - Vector2::new(z.x_m, z.y_m));
    let eyaw = wrap_angle(xj.yaw_rad - xi.yaw_rad - z.yaw_rad);
    // d(R_i^T)/d(theta_i)
    let drit = Matrix2::new(-s, c, -c, -s);
    let d_theta = rz.transpose() * drit * dt;
    let mut a = Matrix3::zeros();
    let mut b = Matrix3::zeros();
    for r in 0..2 {
        for k in 0..2 {
            a[(r, k)] = -rzt_rit[(r, k)];
            b[(r, k)] = rzt_rit[(r, k)];
        }
        a[(r, 2)] = d_theta[r];
    }
    a[(2, 2)] = -1.0;
    b[(2, 2)] = 1.0;
    (Vector3::new(et.x, et.y, eyaw), a, b)
}

/// The error of [`linearise`] without the Jacobians (the cost's inner loop).
fn edge_error(xi: &Pose2, xj: &Pose2, z: &Pose2, rz: &Matrix2<f64>) -> Vector3<f64> {
    let ri = rot(xi.yaw_rad);
    let dt = Vector2::new(xj.x_m - xi.x_m, xj.y_m - xi.y_m);
    let et = rz.transpose() * (ri.transpose() * dt - Vector2::new(z.x_m, z.y_m));
    let eyaw = wrap_angle(xj.yaw_rad - xi.yaw_rad - z.yaw_rad);
    Vector3::new(et.x, et.y, eyaw)
}

fn rot(yaw: f64) -> Matrix2<f64> {
    let (s, c) = yaw.sin_cos();
    Matrix2::new(c, -s, s, c)
}

/// `(robust cost, IRLS weight)` of a squared whitened error.
fn robust(chi2: f64, width: Option<f64>) -> (f64, f64) {
    match width {
        None => (chi2, 1.0),
        Some(c) => {
            let c2 = c * c;
            (c2 * (1.0 + chi2 / c2).ln(), 1.0 / (1.0 + chi2 / c2))
        }
    }
}

impl PoseGraph {
    /// The squared whitened error `e^T Omega e` of edge `k`.
    pub fn edge_chi2(&self, k: usize) -> f64 {
        let e = &self.edges[k];
        self.chi2_of(e, &rot(e.measurement.yaw_rad))
    }

    /// `e^T Omega e` of `edge` (its measurement's rotation `rz`).
    fn chi2_of(&self, edge: &Edge, rz: &Matrix2<f64>) -> f64 {
        let err = edge_error(
            &self.poses[edge.from],
            &self.poses[edge.to],
            &edge.measurement,
            rz,
        );
        (err.transpose() * edge.information * err)[(0, 0)]
    }

    /// The robust cost of the whole graph.
    pub fn cost(&self) -> f64 {
        self.cost_with(&self.measurement_rotations())
    }

    /// Each edge's `rot(measurement.yaw_rad)`.
    fn measurement_rotations(&self) -> Vec<Matrix2<f64>> {
        self.edges
            .iter()
            .map(|e| rot(e.measurement.yaw_rad))
            .collect()
    }

    /// [`Self::cost`] with the measurements' rotations given: the terms in parallel on a
    /// large graph, summed in edge order as the serial sum does (the same bits).
    fn cost_with(&self, rz: &[Matrix2<f64>]) -> f64 {
        let term = |(e, r): (&Edge, &Matrix2<f64>)| robust(self.chi2_of(e, r), e.robust_width).0;
        if self.edges.len() < PARALLEL_COST_EDGES {
            return self.edges.iter().zip(rz).map(term).sum();
        }
        let terms: Vec<f64> = self
            .edges
            .par_iter()
            .zip(rz)
            .with_min_len(PARALLEL_COST_EDGES / 4)
            .map(term)
            .collect();
        terms.into_iter().sum()
    }

    /// Levenberg-Marquardt with node 0 fixed. Edges naming a node beyond `poses` are ignored.
    pub fn optimize(&mut self, opts: &OptimizeOptions) -> OptimizeReport {
        let n = self.poses.len();
        let rz = self.measurement_rotations();
        let initial_cost = self.cost_with(&rz);
        let mut report = OptimizeReport {
            iterations: 0,
            initial_cost,
            final_cost: initial_cost,
        };
        if n < 2 {
            return report;
        }
        // The ordering and the factor's pattern once; the numbers per iteration.
        let mut solver = BlockCholesky::new(n, &self.edges);
        let mut saved = Vec::with_capacity(n);
        let mut lambda = 1e-6;
        let mut cost = initial_cost;
        while report.iterations < opts.max_iterations {
            report.iterations += 1;
            solver.clear();
            for (k, e) in self.edges.iter().enumerate() {
                if e.from >= n || e.to >= n {
                    continue;
                }
                let (err, a, b) = linearise(
                    &self.poses[e.from],
                    &self.poses[e.to],
                    &e.measurement,
                    &rz[k],
                );
                let chi2 = (err.transpose() * e.information * err)[(0, 0)];
                let w = robust(chi2, e.robust_width).1;
                let omega = e.information * w;
                let (oa, ob) = (a.transpose() * omega, b.transpose() * omega);
                solver.add_edge(
                    k,
                    (&(oa * a), &(ob * b), &(ob * a)),
                    (&(-(oa * err)), &(-(ob * err))),
                );
            }
            let mut improved = false;
            for _ in 0..10 {
                if !solver.solve_damped(lambda) {
                    lambda *= 10.0;
                    continue;
                }
                saved.clone_from(&self.poses);
                for node in 1..n {
                    let [dx, dy, dyaw] = solver.step_of(node);
                    let p = &mut self.poses[node];
                    *p = Pose2::new(p.x_m + dx, p.y_m + dy, p.yaw_rad + dyaw);
                }
                let new_cost = self.cost_with(&rz);
                if new_cost < cost {
                    let rel = (cost - new_cost) / cost.max(1e-300);
                    cost = new_cost;
                    lambda = (lambda * 0.1).max(1e-12);
                    improved = rel > opts.relative_tolerance;
                    break;
                }
                self.poses.clone_from(&saved);
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        report.final_cost = cost;
        report
    }
}

/// The free nodes (1..n) in a fill-reducing order, the block structure of the Cholesky
/// factor it gives, and the buffers of the numeric factorisation, all reused across the
/// Levenberg-Marquardt iterations of one [`PoseGraph::optimize`] (the sparsity does not
/// change). Blocks are 3x3, row-major `[f64; 9]`.
struct BlockCholesky {
    /// `perm[node - 1]` = position of the node in the factorisation.
    perm: Vec<usize>,
    /// Column `j`'s off-diagonal blocks (rows below `j`) are `col_ptr[j]..col_ptr[j + 1]`.
    col_ptr: Vec<usize>,
    /// Block row of each off-diagonal block, ascending within a column.
    row_idx: Vec<usize>,
    /// Row `j`'s off-diagonal blocks are `row_ptr[j]..row_ptr[j + 1]` of `row_entries`.
    row_ptr: Vec<usize>,
    /// `(column, block slot)` of row `j`'s blocks, by increasing column.
    row_entries: Vec<(usize, usize)>,
    /// Where each edge adds its blocks.
    edge_slots: Vec<EdgeSlots>,
    /// The normal equations' diagonal and (in the factor's pattern) off-diagonal blocks.
    a_diag: Vec<[f64; 9]>,
    a_off: Vec<[f64; 9]>,
    /// The right-hand side, by position.
    rhs: Vec<f64>,
    /// The factor: lower-triangular diagonal blocks and the blocks below them.
    l_diag: Vec<[f64; 9]>,
    l_off: Vec<[f64; 9]>,
    /// Row -> slot of column `j`'s block in that row (scratch of the factorisation).
    slot_of_row: Vec<usize>,
    /// The solution, by position.
    x: Vec<f64>,
}

/// An edge's blocks: the positions of its two free nodes, and the slot of its
/// off-diagonal block (`true`: stored transposed, the `to` node comes first).
#[derive(Clone, Copy, Default)]
struct EdgeSlots {
    from: Option<usize>,
    to: Option<usize>,
    off: Option<(usize, bool)>,
}

impl BlockCholesky {
    /// Ordering and symbolic factorisation of the graph with `n` nodes (node 0 fixed).
    fn new(n: usize, edges: &[Edge]) -> BlockCholesky {
        let m = n.saturating_sub(1);
        let free = |node: usize| (node != 0 && node < n).then(|| node - 1);
        let pairs = edges
            .iter()
            .filter_map(|e| match (free(e.from), free(e.to)) {
                (Some(a), Some(b)) if a != b => Some((a, b)),
                _ => None,
            });
        let adj = Compressed::from_pairs(m, pairs.flat_map(|(a, b)| [(a, b), (b, a)]));
        let order = postorder(&adj, &minimum_degree_order(&adj));
        let mut perm = vec![0; m];
        for (pos, &v) in order.iter().enumerate() {
            perm[v] = pos;
        }
        // The lower pattern of the permuted matrix, by column.
        let mut lower_pairs = Vec::with_capacity(adj.idx.len() / 2);
        for v in 0..m {
            for &u in adj.row(v) {
                if perm[u] > perm[v] {
                    lower_pairs.push((perm[v], perm[u]));
                }
            }
        }
        let lower = Compressed::from_pairs(m, lower_pairs.iter().copied());
        drop(adj);
        // Column j's pattern: its own entries and its elimination-tree children's
        // patterns below j.
        const NONE: usize = usize::MAX;
        let mut first_child = vec![NONE; m];
        let mut next_sibling = vec![NONE; m];
        let mut mark = vec![NONE; m];
        let mut col_ptr = Vec::with_capacity(m + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0);
        for j in 0..m {
            let start = row_idx.len();
            mark[j] = j;
            for &i in lower.row(j) {
                if mark[i] != j {
                    mark[i] = j;
                    row_idx.push(i);
                }
            }
            let mut c = first_child[j];
            while c != NONE {
                for t in col_ptr[c]..col_ptr[c + 1] {
                    let i = row_idx[t];
                    if mark[i] != j {
                        mark[i] = j;
                        row_idx.push(i);
                    }
                }
                c = next_sibling[c];
            }
            row_idx[start..].sort_unstable();
            col_ptr.push(row_idx.len());
            if let Some(&parent) = row_idx.get(start) {
                next_sibling[j] = first_child[parent];
                first_child[parent] = j;
            }
        }
        // The transpose: each row's blocks by increasing column.
        let mut row_ptr = vec![0; m + 1];
        for &i in &row_idx {
            row_ptr[i + 1] += 1;
        }
        for j in 0..m {
            row_ptr[j + 1] += row_ptr[j];
        }
        let mut fill = row_ptr.clone();
        let mut row_entries = vec![(0, 0); row_idx.len()];
        for k in 0..m {
            for (t, &i) in row_idx
                .iter()
                .enumerate()
                .take(col_ptr[k + 1])
                .skip(col_ptr[k])
            {
                row_entries[fill[i]] = (k, t);
                fill[i] += 1;
            }
        }
        let slot = |row: usize, col: usize| -> Option<usize> {
            let range = col_ptr[col]..col_ptr[col + 1];
            row_idx[range.clone()]
                .binary_search(&row)
                .ok()
                .map(|k| range.start + k)
        };
        let edge_slots = edges
            .iter()
            .map(|e| {
                let (from, to) = (free(e.from), free(e.to));
                if e.from == e.to || e.from >= n || e.to >= n {
                    // A self-edge's error does not depend on the poses.
                    return EdgeSlots::default();
                }
                let (pf, pt) = (from.map(|v| perm[v]), to.map(|v| perm[v]));
                let off = match (pf, pt) {
                    (Some(a), Some(b)) if b > a => slot(b, a).map(|s| (s, false)),
                    (Some(a), Some(b)) => slot(a, b).map(|s| (s, true)),
                    _ => None,
                };
                EdgeSlots {
                    from: pf,
                    to: pt,
                    off,
                }
            })
            .collect();
        let nnz = row_idx.len();
        BlockCholesky {
            perm,
            col_ptr,
            row_idx,
            row_ptr,
            row_entries,
            edge_slots,
            a_diag: vec![[0.0; 9]; m],
            a_off: vec![[0.0; 9]; nnz],
            rhs: vec![0.0; 3 * m],
            l_diag: vec![[0.0; 9]; m],
            l_off: vec![[0.0; 9]; nnz],
            slot_of_row: vec![0; m],
            x: vec![0.0; 3 * m],
        }
    }

    /// The last solution's step of free node `node` (>= 1).
    fn step_of(&self, node: usize) -> [f64; 3] {
        let v = 3 * self.perm[node - 1];
        [self.x[v], self.x[v + 1], self.x[v + 2]]
    }

    /// Zeroes the normal equations.
    fn clear(&mut self) {
        self.a_diag.fill([0.0; 9]);
        self.a_off.fill([0.0; 9]);
        self.rhs.fill(0.0);
    }

    /// Adds edge `k`'s blocks `h_ff`, `h_tt`, `h_tf` (rows of `to`, columns of `from`) and
    /// its gradients `g_f`, `g_t`; the fixed node's share is dropped.
    fn add_edge(
        &mut self,
        k: usize,
        (h_ff, h_tt, h_tf): (&Matrix3<f64>, &Matrix3<f64>, &Matrix3<f64>),
        (g_f, g_t): (&Vector3<f64>, &Vector3<f64>),
    ) {
        let s = self.edge_slots[k];
        for (pos, h, g) in [(s.from, h_ff, g_f), (s.to, h_tt, g_t)] {
            if let Some(p) = pos {
                let d = &mut self.a_diag[p];
                for r in 0..3 {
                    for c in 0..3 {
                        d[3 * r + c] += h[(r, c)];
                    }
                    self.rhs[3 * p + r] += g[r];
                }
            }
        }
        if let Some((slot, transposed)) = s.off {
            let b = &mut self.a_off[slot];
            for r in 0..3 {
                for c in 0..3 {
                    b[3 * r + c] += if transposed {
                        h_tf[(c, r)]
                    } else {
                        h_tf[(r, c)]
                    };
                }
            }
        }
    }

    /// Solves `(H + lambda * diag(H)) x = rhs` (left-looking block Cholesky, then the two
    /// triangular solves) into [`Self::step_of`]; `false` if not positive definite.
    fn solve_damped(&mut self, lambda: f64) -> bool {
        let m = self.l_diag.len();
        for j in 0..m {
            let base = self.col_ptr[j];
            let end = self.col_ptr[j + 1];
            for t in base..end {
                self.slot_of_row[self.row_idx[t]] = t - base;
            }
            let (done, rest) = self.l_off.split_at_mut(base);
            let col = &mut rest[..end - base];
            // The column starts as the normal equations' (copied here, while in cache).
            col.copy_from_slice(&self.a_off[base..end]);
            let mut d = self.a_diag[j];
            for k in [0, 4, 8] {
                d[k] += lambda * d[k].abs().max(1e-9);
            }
            for &(k, s) in &self.row_entries[self.row_ptr[j]..self.row_ptr[j + 1]] {
                let ljk = done[s];
                sub_mul_transposed(&mut d, &ljk, &ljk);
                for t in s + 1..self.col_ptr[k + 1] {
                    let dst = &mut col[self.slot_of_row[self.row_idx[t]]];
                    sub_mul_transposed(dst, &done[t], &ljk);
                }
            }
            let Some(c) = cholesky3(&d) else {
                return false;
            };
            let inv = [1.0 / c[0], 1.0 / c[4], 1.0 / c[8]];
            for b in col.iter_mut() {
                solve_right_transposed(b, &c, &inv);
            }
            self.l_diag[j] = c;
        }
        // Forward: L y = b; backward: L^T x = y.
        let x = &mut self.x;
        x.copy_from_slice(&self.rhs);
        for j in 0..m {
            let c = &self.l_diag[j];
            let y0 = x[3 * j] / c[0];
            let y1 = (x[3 * j + 1] - c[3] * y0) / c[4];
            let y2 = (x[3 * j + 2] - c[6] * y0 - c[7] * y1) / c[8];
            let y = [y0, y1, y2];
            x[3 * j..3 * j + 3].copy_from_slice(&y);
            for t in self.col_ptr[j]..self.col_ptr[j + 1] {
                let (b, i) = (&self.l_off[t], 3 * self.row_idx[t]);
                for r in 0..3 {
                    x[i + r] -= b[3 * r] * y[0] + b[3 * r + 1] * y[1] + b[3 * r + 2] * y[2];
                }
            }
        }
        for j in (0..m).rev() {
            let mut v = [x[3 * j], x[3 * j + 1], x[3 * j + 2]];
            for t in self.col_ptr[j]..self.col_ptr[j + 1] {
                let (b, i) = (&self.l_off[t], 3 * self.row_idx[t]);
                let xi = [x[i], x[i + 1], x[i + 2]];
                for (c, vc) in v.iter_mut().enumerate() {
                    *vc -= b[c] * xi[0] + b[3 + c] * xi[1] + b[6 + c] * xi[2];
                }
            }
            let c = &self.l_diag[j];
            let x2 = v[2] / c[8];
            let x1 = (v[1] - c[7] * x2) / c[4];
            let x0 = (v[0] - c[3] * x1 - c[6] * x2) / c[0];
            x[3 * j..3 * j + 3].copy_from_slice(&[x0, x1, x2]);
        }
        true
    }
}

/// `dst -= a * b^T` (3x3, row-major).
#[inline]
fn sub_mul_transposed(dst: &mut [f64; 9], a: &[f64; 9], b: &[f64; 9]) {
    for r in 0..3 {
        for c in 0..3 {
            dst[3 * r + c] -=
                a[3 * r] * b[3 * c] + a[3 * r + 1] * b[3 * c + 1] + a[3 * r + 2] * b[3 * c + 2];
        }
    }
}

/// The lower Cholesky factor of a symmetric 3x3 block (its lower triangle is read); `None`
/// if not positive definite.
#[inline]
fn cholesky3(d: &[f64; 9]) -> Option<[f64; 9]> {
    let pivot = |s: f64| (s > 0.0 && s.is_finite()).then(|| s.sqrt());
    let l00 = pivot(d[0])?;
    let l10 = d[3] / l00;
    let l20 = d[6] / l00;
    let l11 = pivot(d[4] - l10 * l10)?;
    let l21 = (d[7] - l20 * l10) / l11;
    let l22 = pivot(d[8] - l20 * l20 - l21 * l21)?;
    Some([l00, 0.0, 0.0, l10, l11, 0.0, l20, l21, l22])
}

/// `b <- b * c^-T` for a lower-triangular `c` with diagonal reciprocals `inv` (each row of
/// `b` solves `c y = row`).
#[inline]
fn solve_right_transposed(b: &mut [f64; 9], c: &[f64; 9], inv: &[f64; 3]) {
    for r in 0..3 {
        let y0 = b[3 * r] * inv[0];
        let y1 = (b[3 * r + 1] - c[3] * y0) * inv[1];
        let y2 = (b[3 * r + 2] - c[6] * y0 - c[7] * y1) * inv[2];
        b[3 * r] = y0;
        b[3 * r + 1] = y1;
        b[3 * r + 2] = y2;
    }
}

/// A graph or a sparsity pattern in compressed rows: row `i` is `idx[ptr[i]..ptr[i + 1]]`.
struct Compressed {
    ptr: Vec<usize>,
    idx: Vec<usize>,
}

impl Compressed {
    /// From `(row, column)` pairs; each row sorted, without duplicates.
    fn from_pairs(rows: usize, pairs: impl Iterator<Item = (usize, usize)> + Clone) -> Compressed {
        let mut ptr = vec![0; rows + 1];
        for (r, _) in pairs.clone() {
            ptr[r + 1] += 1;
        }
        for r in 0..rows {
            ptr[r + 1] += ptr[r];
        }
        let mut fill = ptr.clone();
        let mut idx = vec![0; ptr[rows]];
        for (r, c) in pairs {
            idx[fill[r]] = c;
            fill[r] += 1;
        }
        // Sort and compact each row in place (the write position never passes the read).
        let mut w = 0;
        for r in 0..rows {
            let (start, end) = (ptr[r], ptr[r + 1]);
            idx[start..end].sort_unstable();
            ptr[r] = w;
            for k in start..end {
                if w == ptr[r] || idx[w - 1] != idx[k] {
                    idx[w] = idx[k];
                    w += 1;
                }
            }
        }
        ptr[rows] = w;
        idx.truncate(w);
        Compressed { ptr, idx }
    }

    fn row(&self, i: usize) -> &[usize] {
        &self.idx[self.ptr[i]..self.ptr[i + 1]]
    }
}

/// A minimum-degree elimination order of a graph without self-loops (`order[k]` = the k-th
/// node eliminated): on the quotient graph, with AMD's approximate external degrees and
/// element absorption (Amestoy, Davis and Duff 1996), without supervariables (the nodes
/// are already 3x3 blocks). Ties go to the lowest index, so the order depends only on the
/// graph.
fn minimum_degree_order(adj: &Compressed) -> Vec<usize> {
    use std::cmp::Reverse;
    #[derive(Clone, Copy, PartialEq)]
    enum State {
        Variable,
        Element,
        Absorbed,
    }
    const NONE: usize = usize::MAX;
    let m = adj.ptr.len() - 1;
    let mut state = vec![State::Variable; m];
    // A variable's variable neighbours: `vars[vars_at[i]..][..vars_len[i]]`, only shrinking.
    let mut vars = adj.idx.clone();
    let vars_at = &adj.ptr;
    let mut vars_len: Vec<usize> = (0..m).map(|i| adj.ptr[i + 1] - adj.ptr[i]).collect();
    // A variable's adjacent elements.
    let mut elems: Vec<Vec<usize>> = vec![Vec::new(); m];
    // An element's variables: `members[members_at[e]..][..members_len[e]]` (fixed once
    // made: an element holding an eliminated variable has been absorbed).
    let mut members = Vec::new();
    let mut members_at = vec![0; m];
    let mut members_len = vec![0; m];
    let mut degree = vars_len.clone();
    // Stale entries (an old degree, or eliminated) are skipped when popped.
    let mut queue: std::collections::BinaryHeap<Reverse<(usize, usize)>> =
        (0..m).map(|i| Reverse((degree[i], i))).collect();
    let mut in_lp = vec![NONE; m];
    let mut w_step = vec![NONE; m];
    let mut w = vec![0usize; m];
    let mut order = Vec::with_capacity(m);
    while let Some(Reverse((d, p))) = queue.pop() {
        if state[p] != State::Variable || d != degree[p] {
            continue;
        }
        let step = order.len();
        order.push(p);
        let remaining = m - order.len();
        // The new element's variables: p's variables and those of the elements it absorbs.
        let lp_at = members.len();
        in_lp[p] = step;
        for &v in &vars[vars_at[p]..][..vars_len[p]] {
            if in_lp[v] != step {
                in_lp[v] = step;
                members.push(v);
            }
        }
        for &e in &elems[p] {
            if state[e] != State::Element {
                continue;
            }
            for k in members_at[e]..members_at[e] + members_len[e] {
                let v = members[k];
                if in_lp[v] != step {
                    in_lp[v] = step;
                    members.push(v);
                }
            }
            state[e] = State::Absorbed;
        }
        state[p] = State::Element;
        vars_len[p] = 0;
        elems[p] = Vec::new();
        members_at[p] = lp_at;
        members_len[p] = members.len() - lp_at;
        let lp = &members[lp_at..];
        // |Le \ Lp| of every other element next to Lp.
        for &i in lp {
            for &e in &elems[i] {
                if state[e] != State::Element {
                    continue;
                }
                if w_step[e] != step {
                    w_step[e] = step;
                    w[e] = members_len[e];
                }
                w[e] -= 1;
            }
        }
        for &i in lp {
            let mut external = 0;
            elems[i].retain(|&e| {
                if state[e] != State::Element {
                    return false;
                }
                if w[e] == 0 {
                    // Inside Lp: absorbed (its variables keep p instead).
                    state[e] = State::Absorbed;
                    return false;
                }
                external += w[e];
                true
            });
            elems[i].push(p);
            // Variables in Lp are now reached through the element.
            let own = &mut vars[vars_at[i]..][..vars_len[i]];
            let mut kept = 0;
            for k in 0..own.len() {
                if in_lp[own[k]] != step {
                    own[kept] = own[k];
                    kept += 1;
                }
            }
            vars_len[i] = kept;
            let d = (kept + lp.len() - 1 + external)
                .min(degree[i] + lp.len() - 1)
                .min(remaining - 1);
            if d != degree[i] {
                degree[i] = d;
                queue.push(Reverse((d, i)));
            }
        }
    }
    order
}

/// `order` (an elimination order of `adj`) rearranged into a postorder of its elimination
/// tree (children by increasing position): the same factor pattern, but each subtree's
/// columns are contiguous, so the columns that update a column were computed recently.
fn postorder(adj: &Compressed, order: &[usize]) -> Vec<usize> {
    const NONE: usize = usize::MAX;
    let m = order.len();
    let mut pos = vec![0; m];
    for (k, &v) in order.iter().enumerate() {
        pos[v] = k;
    }
    // Liu's elimination tree with path compression through `ancestor`.
    let mut parent = vec![NONE; m];
    let mut ancestor = vec![NONE; m];
    for (k, &v) in order.iter().enumerate() {
        for &u in adj.row(v) {
            let mut i = pos[u];
            if i >= k {
                continue;
            }
            while ancestor[i] != NONE && ancestor[i] != k {
                let next = ancestor[i];
                ancestor[i] = k;
                i = next;
            }
            if ancestor[i] == NONE {
                ancestor[i] = k;
                parent[i] = k;
            }
        }
    }
    // Children lists, ascending (built from the last child to the first).
    let mut first_child = vec![NONE; m];
    let mut next_sibling = vec![NONE; m];
    for j in (0..m).rev() {
        if parent[j] != NONE {
            next_sibling[j] = first_child[parent[j]];
            first_child[parent[j]] = j;
        }
    }
    let mut out = Vec::with_capacity(m);
    let mut stack = Vec::new();
    for root in (0..m).filter(|&j| parent[j] == NONE) {
        stack.push(root);
        while let Some(&top) = stack.last() {
            let child = first_child[top];
            if child == NONE {
                stack.pop();
                out.push(order[top]);
            } else {
                // Descend into the first child not yet visited.
                first_child[top] = next_sibling[child];
                stack.push(child);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobians_match_finite_differences() {
        let xi = Pose2::new(1.0, -2.0, 0.7);
        let xj = Pose2::new(2.5, 0.3, -2.9);
        let z = Pose2::new(0.4, 1.1, 0.2);
        let (e0, a, b) = linearise(&xi, &xj, &z, &rot(z.yaw_rad));
        // The cost's error is the linearisation's, bit for bit.
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let mut pose = || {
            Pose2::new(
                rng.random_range(-50.0..50.0),
                rng.random_range(-50.0..50.0),
                rng.random_range(-4.0..4.0),
            )
        };
        for _ in 0..2000 {
            let (p, q, r) = (pose(), pose(), pose());
            let rr = rot(r.yaw_rad);
            let (fast, slow) = (edge_error(&p, &q, &r, &rr), linearise(&p, &q, &r, &rr).0);
            for k in 0..3 {
                assert_eq!(fast[k].to_bits(), slow[k].to_bits());
            }
        }
        let h = 1e-6;
        for k in 0..3 {
            let bump = |p: &Pose2| {
                let mut v = [p.x_m, p.y_m, p.yaw_rad];
                v[k] += h;
                Pose2::new(v[0], v[1], v[2])
            };
            let (ei, _, _) = linearise(&bump(&xi), &xj, &z, &rot(z.yaw_rad));
            let (ej, _, _) = linearise(&xi, &bump(&xj), &z, &rot(z.yaw_rad));
            for r in 0..3 {
                assert!(((ei[r] - e0[r]) / h - a[(r, k)]).abs() < 1e-4, "A {r} {k}");
                assert!(((ej[r] - e0[r]) / h - b[(r, k)]).abs() < 1e-4, "B {r} {k}");
            }
        }
    }

    use nalgebra::DMatrix;
    use rand::{RngExt, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// A chain of `n` nodes with loop closures between far-apart nodes (bunched, as
    /// revisits are) and a prior on every node (an edge from the fixed node 0).
    fn loopy_structure(n: usize, rng: &mut Xoshiro256PlusPlus) -> Vec<(usize, usize)> {
        let mut pairs: Vec<(usize, usize)> = (1..n).map(|k| (k - 1, k)).collect();
        pairs.extend((2..n).map(|k| (0, k)));
        for k in 10..n {
            if rng.random::<f64>() < 0.3 {
                let j = rng.random_range(0..k - 5);
                for d in 0..3.min(n - k) {
                    pairs.push((j + d, k + d));
                }
            }
        }
        pairs
    }

    fn random_block(rng: &mut Xoshiro256PlusPlus) -> Matrix3<f64> {
        Matrix3::from_fn(|_, _| rng.random_range(-1.0..1.0))
    }

    /// Random normal equations `sum J^T W J`, `-J^T W e` on `pairs`, in the sparse solver
    /// and densely (free nodes 1.., `3 * (node - 1) + axis`).
    fn random_system(
        n: usize,
        pairs: &[(usize, usize)],
        rng: &mut Xoshiro256PlusPlus,
    ) -> (BlockCholesky, DMatrix<f64>, Vec<f64>) {
        let edges: Vec<Edge> = pairs
            .iter()
            .map(|&(a, b)| Edge::with_sigmas(a, b, Pose2::default(), 1.0, 1.0, None))
            .collect();
        let mut solver = BlockCholesky::new(n, &edges);
        solver.clear();
        let m = 3 * (n - 1);
        let mut dense = DMatrix::zeros(m, m);
        let mut rhs = vec![0.0; m];
        for (k, &(a, b)) in pairs.iter().enumerate() {
            let (ja, jb) = (random_block(rng), random_block(rng));
            let root = random_block(rng);
            let w = root * root.transpose() + Matrix3::identity() * 0.5;
            let e = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let (wa, wb) = (ja.transpose() * w, jb.transpose() * w);
            let (haa, hbb, hba) = (wa * ja, wb * jb, wb * ja);
            let (ga, gb) = (-(wa * e), -(wb * e));
            solver.add_edge(k, (&haa, &hbb, &hba), (&ga, &gb));
            let mut put = |r: usize, c: usize, h: &Matrix3<f64>| {
                if r > 0 && c > 0 {
                    let mut view = dense.fixed_view_mut::<3, 3>(3 * (r - 1), 3 * (c - 1));
                    view += h;
                }
            };
            put(a, a, &haa);
            put(b, b, &hbb);
            put(b, a, &hba);
            put(a, b, &hba.transpose());
            for (node, g) in [(a, ga), (b, gb)] {
                if node > 0 {
                    for r in 0..3 {
                        rhs[3 * (node - 1) + r] += g[r];
                    }
                }
            }
        }
        (solver, dense, rhs)
    }

    #[test]
    fn sparse_solve_matches_a_dense_solve() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
        for n in [2, 3, 8, 60, 400] {
            let pairs = loopy_structure(n, &mut rng);
            let (mut solver, dense, rhs) = random_system(n, &pairs, &mut rng);
            for lambda in [0.0, 1e-6, 0.1, 10.0] {
                let mut damped = dense.clone();
                for r in 0..damped.nrows() {
                    damped[(r, r)] += lambda * damped[(r, r)].abs().max(1e-9);
                }
                let truth = damped
                    .cholesky()
                    .expect("positive definite")
                    .solve(&nalgebra::DVector::from_column_slice(&rhs));
                assert!(solver.solve_damped(lambda), "n {n} lambda {lambda}");
                let scale = truth.amax();
                let mut worst: f64 = 0.0;
                for node in 1..n {
                    let got = solver.step_of(node);
                    for r in 0..3 {
                        worst = worst.max((got[r] - truth[3 * (node - 1) + r]).abs());
                    }
                }
                assert!(
                    worst <= 1e-9 * scale,
                    "n {n} lambda {lambda}: {worst} vs {scale}"
                );
            }
        }
    }

    #[test]
    fn non_positive_definite_system_is_refused() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        let n = 200;
        let pairs = loopy_structure(n, &mut rng);
        for node in [1, 77, 199] {
            let (mut solver, _, _) = random_system(n, &pairs, &mut rng);
            assert!(solver.solve_damped(1e-6));
            // A negative curvature on one node (through its prior edge's block).
            let k = pairs.iter().position(|&p| p == (0, node)).unwrap_or(0);
            let zero = Matrix3::zeros();
            let g = Vector3::zeros();
            solver.add_edge(k, (&zero, &(Matrix3::identity() * -1e6), &zero), (&g, &g));
            assert!(!solver.solve_damped(1e-6), "node {node}");
            // The same system again after the refusal (buffers reused): still refused.
            assert!(!solver.solve_damped(1e-6), "node {node}");
        }
    }

    #[test]
    fn minimum_degree_order_is_a_permutation_without_fill_on_a_tree() {
        // A tree (a chain with side branches): eliminating leaves first creates no fill.
        let n = 300;
        let mut edges = Vec::new();
        for k in 1..n {
            let parent = if k % 7 == 0 { k / 2 } else { k - 1 };
            edges.push(Edge::with_sigmas(
                parent,
                k,
                Pose2::default(),
                1.0,
                1.0,
                None,
            ));
        }
        let solver = BlockCholesky::new(n, &edges);
        let free_edges = edges.iter().filter(|e| e.from != 0).count();
        assert_eq!(solver.row_idx.len(), free_edges);
        let mut seen = solver.perm.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..n - 1).collect::<Vec<_>>());
        // Loops do fill, but far less than the dense triangle.
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
        let pairs = loopy_structure(n, &mut rng);
        let (solver, _, _) = random_system(n, &pairs, &mut rng);
        let m = n - 1;
        assert!(
            solver.row_idx.len() < m * (m - 1) / 20,
            "{}",
            solver.row_idx.len()
        );
    }

    /// A corridor driven in laps, closures between laps, from drifted odometry.
    fn lapped_graph(per_lap: usize, laps: usize) -> PoseGraph {
        let n = per_lap * laps;
        let pose = |k: usize| {
            let t = (k % per_lap) as f64 / per_lap as f64 * std::f64::consts::TAU;
            let r = 1.0 + 0.02 * (k / per_lap) as f64;
            Pose2::new(8.0 * r * t.cos(), 5.0 * r * t.sin(), t + 1.5)
        };
        let mut graph = PoseGraph::default();
        let mut odo = pose(0);
        graph.poses.push(odo);
        for k in 1..n {
            let mut z = pose(k - 1).between(&pose(k));
            z.yaw_rad += 0.003 * ((k * 7 % 5) as f64 - 1.5);
            graph
                .edges
                .push(Edge::with_sigmas(k - 1, k, z, 0.05, 0.02, None));
            odo = odo.compose(&z);
            graph.poses.push(odo);
        }
        for k in (per_lap..n).step_by(4) {
            let j = k - per_lap + (k * 13) % 3;
            let mut z = pose(j).between(&pose(k));
            z.x_m += 0.01;
            graph
                .edges
                .push(Edge::with_sigmas(j, k, z, 0.1, 0.03, Some(3.0)));
        }
        graph
    }

    #[test]
    fn parallel_cost_is_the_serial_sum() {
        // 5,000 nodes, 6,250 edges: the parallel branch; 400 nodes: the serial one.
        for graph in [lapped_graph(1000, 5), lapped_graph(100, 4)] {
            let serial: f64 = (0..graph.edges.len())
                .map(|k| robust(graph.edge_chi2(k), graph.edges[k].robust_width).0)
                .sum();
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("pool");
                assert_eq!(pool.install(|| graph.cost()).to_bits(), serial.to_bits());
            }
            assert!(serial > 1.0);
        }
    }

    #[test]
    fn optimisation_has_the_same_bits_on_any_thread_count() {
        for graph in [lapped_graph(100, 4), lapped_graph(1000, 5)] {
            same_bits_on_any_thread_count(&graph);
        }
    }

    fn same_bits_on_any_thread_count(graph: &PoseGraph) {
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| {
                let mut g = graph.clone();
                let report = g.optimize(&OptimizeOptions::default());
                (g, report)
            })
        };
        let (one, r1) = run(1);
        assert!(r1.final_cost < 0.01 * r1.initial_cost, "{r1:?}");
        for threads in [2, 3] {
            let (other, r) = run(threads);
            assert_eq!(r1.final_cost.to_bits(), r.final_cost.to_bits());
            for (a, b) in one.poses.iter().zip(&other.poses) {
                for (u, v) in [(a.x_m, b.x_m), (a.y_m, b.y_m), (a.yaw_rad, b.yaw_rad)] {
                    assert_eq!(u.to_bits(), v.to_bits());
                }
            }
        }
    }

    #[test]
    fn cholesky_solves_a_chain_with_a_long_edge() {
        // A chain with one closure: the solution must satisfy every edge exactly (consistent
        // measurements), from a perturbed start.
        let truth: Vec<Pose2> = (0..30)
            .map(|k| {
                Pose2::new(
                    f64::from(k).cos() * 3.0,
                    f64::from(k).sin() * 2.0,
                    0.1 * f64::from(k),
                )
            })
            .collect();
        let mut g = PoseGraph::default();
        for k in 1..truth.len() {
            g.edges.push(Edge::with_sigmas(
                k - 1,
                k,
                truth[k - 1].between(&truth[k]),
                0.1,
                0.01,
                None,
            ));
        }
        g.edges.push(Edge::with_sigmas(
            3,
            27,
            truth[3].between(&truth[27]),
            0.1,
            0.01,
            None,
        ));
        g.poses = truth
            .iter()
            .enumerate()
            .map(|(k, p)| {
                if k == 0 {
                    *p
                } else {
                    Pose2::new(p.x_m + 0.3, p.y_m - 0.2, p.yaw_rad + 0.05)
                }
            })
            .collect();
        let r = g.optimize(&OptimizeOptions::default());
        assert!(r.final_cost < 1e-12, "{r:?}");
        for (p, t) in g.poses.iter().zip(&truth) {
            assert!(p.between(t).translation_norm_m() < 1e-6);
        }
    }
}
