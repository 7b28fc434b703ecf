//! Sparse SE(2) pose-graph optimisation: Levenberg-Marquardt on the 3x3-block normal
//! equations, solved by an envelope (skyline) Cholesky factorisation after a reverse
//! Cuthill-McKee ordering of the nodes. Loop-closure edges may carry a Cauchy kernel
//! (iteratively reweighted), so a wrong closure loses its pull instead of bending the map.
//!
//! Error of an edge `i -> j` with measurement `z` (pose of `j` in the frame of `i`):
//! `e = t2v(z^-1 * (x_i^-1 * x_j))`, Jacobians as in Grisetti et al., "A tutorial on
//! graph-based SLAM" (2010). Node 0 is held fixed (the gauge).

use crate::geometry::{Pose2, wrap_angle};
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};

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

/// Error, and Jacobians with respect to `x_i` and `x_j`, of one edge.
fn linearise(xi: &Pose2, xj: &Pose2, z: &Pose2) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>) {
    let ri = rot(xi.yaw_rad);
    let rz = rot(z.yaw_rad);
    let dt = Vector2::new(xj.x_m - xi.x_m, xj.y_m - xi.y_m);
    let rzt_rit = rz.transpose() * ri.transpose();
    let et = rz.transpose() * (ri.transpose() * dt - Vector2::new(z.x_m, z.y_m));
    let eyaw = wrap_angle(xj.yaw_rad - xi.yaw_rad - z.yaw_rad);
    let (s, c) = xi.yaw_rad.sin_cos();
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
        let (err, _, _) = linearise(&self.poses[e.from], &self.poses[e.to], &e.measurement);
        (err.transpose() * e.information * err)[(0, 0)]
    }

    /// The robust cost of the whole graph.
    pub fn cost(&self) -> f64 {
        (0..self.edges.len())
            .map(|k| robust(self.edge_chi2(k), self.edges[k].robust_width).0)
            .sum()
    }

    /// Levenberg-Marquardt with node 0 fixed. Edges naming a node beyond `poses` are ignored.
    pub fn optimize(&mut self, opts: &OptimizeOptions) -> OptimizeReport {
        let n = self.poses.len();
        let initial_cost = self.cost();
        let mut report = OptimizeReport {
            iterations: 0,
            initial_cost,
            final_cost: initial_cost,
        };
        if n < 2 {
            return report;
        }
        let order = SparseOrder::new(n, &self.edges);
        let mut lambda = 1e-6;
        let mut cost = initial_cost;
        while report.iterations < opts.max_iterations {
            report.iterations += 1;
            let mut system = order.empty_system();
            for e in &self.edges {
                if e.from >= n || e.to >= n {
                    continue;
                }
                let (err, a, b) = linearise(&self.poses[e.from], &self.poses[e.to], &e.measurement);
                let chi2 = (err.transpose() * e.information * err)[(0, 0)];
                let w = robust(chi2, e.robust_width).1;
                let omega = e.information * w;
                let (oa, ob) = (a.transpose() * omega, b.transpose() * omega);
                system.add(e.from, e.from, &(oa * a), &order);
                system.add(e.to, e.to, &(ob * b), &order);
                system.add(e.to, e.from, &(ob * a), &order);
                system.add_rhs(e.from, &(-(oa * err)), &order);
                system.add_rhs(e.to, &(-(ob * err)), &order);
            }
            let mut improved = false;
            for _ in 0..10 {
                let Some(dx) = system.solve_damped(lambda) else {
                    lambda *= 10.0;
                    continue;
                };
                let saved = self.poses.clone();
                for node in 1..n {
                    let v = order.perm[node - 1] * 3;
                    let p = &mut self.poses[node];
                    *p = Pose2::new(p.x_m + dx[v], p.y_m + dx[v + 1], p.yaw_rad + dx[v + 2]);
                }
                let new_cost = self.cost();
                if new_cost < cost {
                    let rel = (cost - new_cost) / cost.max(1e-300);
                    cost = new_cost;
                    lambda = (lambda * 0.1).max(1e-12);
                    improved = rel > opts.relative_tolerance;
                    break;
                }
                self.poses = saved;
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

/// The fill-reducing order of the free nodes (1..n) and the envelope it gives.
struct SparseOrder {
    /// `perm[node - 1]` = position of the node in the factorisation.
    perm: Vec<usize>,
    /// First scalar column of each scalar row's envelope (in permuted order).
    first_col: Vec<usize>,
}

/// The normal equations in envelope storage.
#[derive(Clone)]
struct System {
    /// Row `r` holds columns `first_col[r]..=r`.
    rows: Vec<Vec<f64>>,
    first_col: Vec<usize>,
    rhs: Vec<f64>,
}

impl SparseOrder {
    fn new(n: usize, edges: &[Edge]) -> SparseOrder {
        let m = n - 1;
        let mut adj: Vec<Vec<usize>> = vec![Vec::new(); m];
        for e in edges {
            if e.from == 0 || e.to == 0 || e.from >= n || e.to >= n || e.from == e.to {
                continue;
            }
            adj[e.from - 1].push(e.to - 1);
            adj[e.to - 1].push(e.from - 1);
        }
        for a in &mut adj {
            a.sort_unstable();
            a.dedup();
        }
        let order = reverse_cuthill_mckee(&adj);
        let mut perm = vec![0; m];
        for (pos, &v) in order.iter().enumerate() {
            perm[v] = pos;
        }
        let mut first_block: Vec<usize> = (0..m).collect();
        for (v, a) in adj.iter().enumerate() {
            let pv = perm[v];
            for &u in a {
                let pu = perm[u];
                if pu < pv {
                    first_block[pv] = first_block[pv].min(pu);
                }
            }
        }
        let first_col = (0..3 * m).map(|r| 3 * first_block[r / 3]).collect();
        SparseOrder { perm, first_col }
    }

    fn empty_system(&self) -> System {
        let rows = self
            .first_col
            .iter()
            .enumerate()
            .map(|(r, &f)| vec![0.0; r - f + 1])
            .collect();
        System {
            rows,
            first_col: self.first_col.clone(),
            rhs: vec![0.0; self.first_col.len()],
        }
    }
}

impl System {
    /// Adds block `h` at (node_a, node_b) (and its transpose); node 0 is skipped.
    fn add(&mut self, node_a: usize, node_b: usize, h: &Matrix3<f64>, order: &SparseOrder) {
        if node_a == 0 || node_b == 0 {
            return;
        }
        let (pa, pb) = (order.perm[node_a - 1] * 3, order.perm[node_b - 1] * 3);
        for r in 0..3 {
            for c in 0..3 {
                let (row, col, v) = (pa + r, pb + c, h[(r, c)]);
                if node_a == node_b {
                    if col <= row {
                        self.rows[row][col - self.first_col[row]] += v;
                    }
                } else if col < row {
                    self.rows[row][col - self.first_col[row]] += v;
                } else {
                    // The transpose lies in the lower triangle.
                    self.rows[col][row - self.first_col[col]] += v;
                }
            }
        }
    }

    fn add_rhs(&mut self, node: usize, g: &Vector3<f64>, order: &SparseOrder) {
        if node == 0 {
            return;
        }
        let p = order.perm[node - 1] * 3;
        for k in 0..3 {
            self.rhs[p + k] += g[k];
        }
    }

    /// Solves `(H + lambda * diag(H)) dx = rhs` by envelope Cholesky; `None` if not
    /// positive definite. Large systems are factorised by two threads (when the pool has
    /// two), with the same bits.
    fn solve_damped(&self, lambda: f64) -> Option<Vec<f64>> {
        let two = rayon::current_num_threads() >= 2 && self.rows.len() >= PIPELINE_MIN_ROWS;
        self.solve_damped_with(lambda, two)
    }

    /// [`Self::solve_damped`], on one thread or two (`pipelined`).
    fn solve_damped_with(&self, lambda: f64, pipelined: bool) -> Option<Vec<f64>> {
        let n = self.rows.len();
        let mut l = self.rows.clone();
        for (r, row) in l.iter_mut().enumerate() {
            let d = r - self.first_col[r];
            row[d] += lambda * row[d].abs().max(1e-9);
        }
        // Every node's three rows share their envelope's first column (`SparseOrder` builds
        // it per node), which the node kernel relies on.
        let by_node = n.is_multiple_of(3)
            && (0..n).step_by(3).all(|r| {
                self.first_col[r + 1] == self.first_col[r]
                    && self.first_col[r + 2] == self.first_col[r]
            });
        if !by_node {
            return None;
        }
        let l = if pipelined {
            factor_pipelined(l, &self.first_col)?
        } else {
            let mut done: Vec<Vec<f64>> = Vec::with_capacity(n);
            let mut it = l.into_iter();
            while let (Some(a), Some(b), Some(c)) = (it.next(), it.next(), it.next()) {
                let mut rows = [a, b, c];
                let r0 = done.len();
                factor_columns(&mut rows, r0, &self.first_col, (0, r0), |c| {
                    Some(&done[c][..])
                })?;
                factor_diagonal(&mut rows, r0, &self.first_col)?;
                done.extend(rows);
            }
            done
        };
        // Forward: L y = b; backward: L^T x = y.
        let mut y = self.rhs.clone();
        for r in 0..n {
            let fr = self.first_col[r];
            let mut s = y[r];
            for k in fr..r {
                s -= l[r][k - fr] * y[k];
            }
            y[r] = s / l[r][r - fr];
        }
        for r in (0..n).rev() {
            let fr = self.first_col[r];
            y[r] /= l[r][r - fr];
            let v = y[r];
            for k in fr..r {
                y[k] -= l[r][k - fr] * v;
            }
        }
        Some(y)
    }
}

/// Below this many rows the factorisation stays on one thread (a thread per solve costs
/// tens of microseconds).
const PIPELINE_MIN_ROWS: usize = 600;

/// Nodes per work unit of the two-thread factorisation: a unit waits (at most) once for
/// the other thread's previous unit.
const PIPELINE_NODES: usize = 8;

/// Columns `c_lo..c_hi` (all `< r0`, clipped to the envelope) of rows `r0..r0 + 3` (one
/// node, sharing the envelope's first column) of the envelope Cholesky factor, in place;
/// `done(c)` gives the finished row `c` (`None`: give up). These entries depend only on
/// earlier rows and the rows' own earlier entries, so the three rows are computed together
/// (three independent dot products per column, each in `dot`'s exact order: the same bits
/// as row by row). Columns must be done in increasing order.
#[inline]
fn factor_columns<'a>(
    rows: &mut [Vec<f64>; 3],
    r0: usize,
    first_col: &[usize],
    (c_lo, c_hi): (usize, usize),
    done: impl Fn(usize) -> Option<&'a [f64]>,
) -> Option<()> {
    let fr = first_col[r0];
    let [ra, rb, rc] = rows;
    for c in fr.max(c_lo)..c_hi {
        let row_c = done(c)?;
        let fc = first_col[c];
        let k0 = fr.max(fc);
        let (lo, hi) = (k0 - fr, c - fr);
        let col = &row_c[k0 - fc..c - fc];
        let d = dot3([&ra[lo..hi], &rb[lo..hi], &rc[lo..hi]], col);
        let diag = row_c[c - fc];
        ra[hi] = (ra[hi] - d[0]) / diag;
        rb[hi] = (rb[hi] - d[1]) / diag;
        rc[hi] = (rc[hi] - d[2]) / diag;
    }
    Some(())
}

/// The node's 3x3 diagonal block, row by row, after all its columns left of it; `None` if
/// not positive definite.
#[inline]
fn factor_diagonal(rows: &mut [Vec<f64>; 3], r0: usize, first_col: &[usize]) -> Option<()> {
    let fr = first_col[r0];
    for i in 0..3 {
        let r = r0 + i;
        let (before, rest) = rows.split_at_mut(i);
        let row = &mut rest[0];
        for c in r0..=r {
            let mut sum = row[c - fr];
            if c == r {
                let own = &row[..c - fr];
                sum -= dot(own, own);
                if sum <= 0.0 || !sum.is_finite() {
                    return None;
                }
                row[c - fr] = sum.sqrt();
            } else {
                let other = &before[c - r0];
                sum -= dot(&row[..c - fr], &other[..c - fr]);
                row[c - fr] = sum / other[c - fr];
            }
        }
    }
    Some(())
}

/// One work unit of [`factor_pipelined`]: consecutive nodes and their rows.
type Unit = Vec<[Vec<f64>; 3]>;

/// The factorisation on two threads, the same bits as on one (every entry is computed by
/// the same expression; only the order between independent entries changes). The nodes
/// are cut into units of [`PIPELINE_NODES`] that alternate between the threads. A unit's
/// columns left of the previous unit need only older units, so a thread computes them
/// while the other thread finishes the previous unit; then it waits for that unit and
/// does the remaining columns and the diagonal blocks. Waiting blocks (no spinning on a
/// shared machine).
fn factor_pipelined(l: Vec<Vec<f64>>, first_col: &[usize]) -> Option<Vec<Vec<f64>>> {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::{Condvar, Mutex, OnceLock};
    let nodes = l.len() / 3;
    let k = PIPELINE_NODES;
    let units = nodes.div_ceil(k);
    let finished: Vec<OnceLock<Unit>> = (0..units).map(|_| OnceLock::new()).collect();
    let failed = AtomicBool::new(false);
    let signal = (Mutex::new(()), Condvar::new());
    let mut lanes: [Vec<(usize, Unit)>; 2] = [Vec::new(), Vec::new()];
    let mut it = l.into_iter();
    for u in 0..units {
        let mut unit = Vec::with_capacity(k);
        while unit.len() < k {
            match (it.next(), it.next(), it.next()) {
                (Some(a), Some(b), Some(c)) => unit.push([a, b, c]),
                _ => break,
            }
        }
        lanes[u % 2].push((u, unit));
    }
    let [even, odd] = lanes;
    let (cells, failed_ref, signal_ref) = (&finished, &failed, &signal);
    // Unit `u` finished, or `None` once the other thread gave up.
    let wait = move |u: usize| -> Option<&Unit> {
        if let Some(unit) = cells[u].get() {
            return Some(unit);
        }
        let mut guard = signal_ref
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        loop {
            if let Some(unit) = cells[u].get() {
                return Some(unit);
            }
            if failed_ref.load(Ordering::Acquire) {
                return None;
            }
            guard = signal_ref
                .1
                .wait(guard)
                .unwrap_or_else(std::sync::PoisonError::into_inner);
        }
    };
    let publish = move |u: usize, unit: Option<Unit>| {
        match unit {
            // Each cell is set once, by its lane.
            Some(unit) => drop(cells[u].set(unit)),
            None => failed_ref.store(true, Ordering::Release),
        }
        // Under the lock, so a waiter cannot miss it between its check and its wait.
        let _guard = signal_ref
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        signal_ref.1.notify_all();
    };
    let row_of = move |c: usize| -> Option<&[f64]> {
        let node = c / 3;
        wait(node / k).map(|unit| &unit[node % k][c % 3][..])
    };
    let run = move |lane: Vec<(usize, Unit)>| {
        for (u, mut unit) in lane {
            let first = u * k;
            // Columns before the previous unit: older units only.
            let before_prev = 3 * first.saturating_sub(k);
            let mut ok = unit.iter_mut().enumerate().all(|(i, rows)| {
                factor_columns(rows, 3 * (first + i), first_col, (0, before_prev), row_of).is_some()
            });
            // Then the previous unit's columns, the unit's own and the diagonal blocks.
            for i in 0..unit.len() {
                if !ok {
                    break;
                }
                let r0 = 3 * (first + i);
                let (own, rest) = unit.split_at_mut(i);
                let rows = &mut rest[0];
                let own_or_older = |c: usize| -> Option<&[f64]> {
                    let node = c / 3;
                    if node >= first {
                        Some(&own[node - first][c % 3][..])
                    } else {
                        row_of(c)
                    }
                };
                ok = factor_columns(rows, r0, first_col, (before_prev, r0), own_or_older)
                    .and_then(|()| factor_diagonal(rows, r0, first_col))
                    .is_some();
            }
            publish(u, ok.then_some(unit));
            if !ok {
                return;
            }
        }
    };
    std::thread::scope(|s| {
        let other = s.spawn(move || run(odd));
        run(even);
        // A panic in the other lane would be a bug; its units are then missing (below).
        let _ = other.join();
    });
    if failed.load(Ordering::Acquire) {
        return None;
    }
    let mut out = Vec::with_capacity(3 * nodes);
    for cell in finished {
        for rows in cell.into_inner()? {
            out.extend(rows);
        }
    }
    Some(out)
}

/// Three dot products of `a[k]` with `b` at once, each in exactly [`dot`]'s order.
#[inline]
fn dot3(a: [&[f64]; 3], b: &[f64]) -> [f64; 3] {
    let n = b.len().min(a[0].len()).min(a[1].len()).min(a[2].len());
    let b = &b[..n];
    let a = a.map(|x| &x[..n]);
    let mut acc = [[0.0; 4]; 3];
    let full = n - n % 4;
    let mut i = 0;
    while i < full {
        let y = &b[i..i + 4];
        for (r, acc) in acc.iter_mut().enumerate() {
            let x = &a[r][i..i + 4];
            for k in 0..4 {
                acc[k] += x[k] * y[k];
            }
        }
        i += 4;
    }
    let mut out = [0.0; 3];
    for r in 0..3 {
        let tail: f64 = a[r][full..]
            .iter()
            .zip(&b[full..])
            .map(|(x, y)| x * y)
            .sum();
        let acc = &acc[r];
        out[r] = (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail;
    }
    out
}

/// Dot product with four accumulators (the factorisation's inner loop).
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0; 4];
    let mut ca = a.chunks_exact(4);
    let mut cb = b.chunks_exact(4);
    for (x, y) in (&mut ca).zip(&mut cb) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// Reverse Cuthill-McKee order of a graph given by sorted adjacency lists: each component
/// from a pseudo-peripheral node, neighbours by increasing degree.
fn reverse_cuthill_mckee(adj: &[Vec<usize>]) -> Vec<usize> {
    let m = adj.len();
    let mut visited = vec![false; m];
    let mut order = Vec::with_capacity(m);
    let bfs_last = |start: usize, visited: &[bool]| -> usize {
        let mut seen = visited.to_vec();
        let mut queue = std::collections::VecDeque::from([start]);
        seen[start] = true;
        let mut last = start;
        while let Some(v) = queue.pop_front() {
            last = v;
            for &u in &adj[v] {
                if !seen[u] {
                    seen[u] = true;
                    queue.push_back(u);
                }
            }
        }
        last
    };
    for s in 0..m {
        if visited[s] {
            continue;
        }
        // Two BFS sweeps find a node far from the rest (a pseudo-peripheral start).
        let start = bfs_last(bfs_last(s, &visited), &visited);
        let begin = order.len();
        let mut queue = std::collections::VecDeque::from([start]);
        visited[start] = true;
        while let Some(v) = queue.pop_front() {
            order.push(v);
            let mut next: Vec<usize> = adj[v].iter().copied().filter(|&u| !visited[u]).collect();
            next.sort_by_key(|&u| (adj[u].len(), u));
            for u in next {
                visited[u] = true;
                queue.push_back(u);
            }
        }
        order[begin..].reverse();
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobians_match_finite_differences() {
        let xi = Pose2::new(1.0, -2.0, 0.7);
        let xj = Pose2::new(2.5, 0.3, -2.9);
        let z = Pose2::new(0.4, 1.1, 0.2);
        let (e0, a, b) = linearise(&xi, &xj, &z);
        let h = 1e-6;
        for k in 0..3 {
            let bump = |p: &Pose2| {
                let mut v = [p.x_m, p.y_m, p.yaw_rad];
                v[k] += h;
                Pose2::new(v[0], v[1], v[2])
            };
            let (ei, _, _) = linearise(&bump(&xi), &xj, &z);
            let (ej, _, _) = linearise(&xi, &bump(&xj), &z);
            for r in 0..3 {
                assert!(((ei[r] - e0[r]) / h - a[(r, k)]).abs() < 1e-4, "A {r} {k}");
                assert!(((ej[r] - e0[r]) / h - b[(r, k)]).abs() < 1e-4, "B {r} {k}");
            }
        }
    }

    /// The envelope factorisation written row by row (before the three-row kernel).
    fn solve_damped_plain(sys: &System, lambda: f64) -> Option<Vec<f64>> {
        let n = sys.rows.len();
        let mut l = sys.rows.clone();
        for (r, row) in l.iter_mut().enumerate() {
            let d = r - sys.first_col[r];
            row[d] += lambda * row[d].abs().max(1e-9);
        }
        for r in 0..n {
            let fr = sys.first_col[r];
            for c in fr..=r {
                let fc = sys.first_col[c];
                let k0 = fr.max(fc);
                let mut sum = l[r][c - fr];
                if c == r {
                    let row = &l[r][k0 - fr..c - fr];
                    sum -= dot(row, row);
                    if sum <= 0.0 || !sum.is_finite() {
                        return None;
                    }
                    l[r][c - fr] = sum.sqrt();
                } else {
                    sum -= dot(&l[r][k0 - fr..c - fr], &l[c][k0 - fc..c - fc]);
                    l[r][c - fr] = sum / l[c][c - fc];
                }
            }
        }
        let mut y = sys.rhs.clone();
        for r in 0..n {
            let fr = sys.first_col[r];
            let mut s = y[r];
            for k in fr..r {
                s -= l[r][k - fr] * y[k];
            }
            y[r] = s / l[r][r - fr];
        }
        for r in (0..n).rev() {
            let fr = sys.first_col[r];
            y[r] /= l[r][r - fr];
            let v = y[r];
            for k in fr..r {
                y[k] -= l[r][k - fr] * v;
            }
        }
        Some(y)
    }

    #[test]
    fn three_row_factorisation_gives_the_row_by_row_bits() {
        // A long chain with many closures (wide, uneven envelopes), linearised away from
        // the solution.
        let n = 300;
        let pose = |k: usize| {
            let t = k as f64 * 0.05;
            Pose2::new(5.0 * t.cos() + 0.01 * k as f64, 3.0 * t.sin(), t + 1.5)
        };
        let mut graph = PoseGraph {
            poses: (0..n).map(pose).collect(),
            edges: Vec::new(),
        };
        let mut push = |a: usize, b: usize, noise: f64| {
            let mut z = pose(a).between(&pose(b));
            z.x_m += noise;
            z.yaw_rad += 0.1 * noise;
            graph
                .edges
                .push(Edge::with_sigmas(a, b, z, 0.05, 0.02, Some(3.0)));
        };
        for k in 1..n {
            push(k - 1, k, 0.01 * ((k * 7 % 5) as f64 - 2.0));
        }
        for k in (40..n).step_by(3) {
            push(k - 40 + (k * 13) % 17, k, 0.02);
            push((k * 31) % (k / 2), k, -0.03);
        }
        let order = SparseOrder::new(n, &graph.edges);
        let mut system = order.empty_system();
        for e in &graph.edges {
            let (err, a, b) = linearise(&graph.poses[e.from], &graph.poses[e.to], &e.measurement);
            let (oa, ob) = (a.transpose() * e.information, b.transpose() * e.information);
            system.add(e.from, e.from, &(oa * a), &order);
            system.add(e.to, e.to, &(ob * b), &order);
            system.add(e.to, e.from, &(ob * a), &order);
            system.add_rhs(e.from, &(-(oa * err)), &order);
            system.add_rhs(e.to, &(-(ob * err)), &order);
        }
        for lambda in [0.0, 1e-6, 1e-2, 10.0] {
            let plain = solve_damped_plain(&system, lambda).expect("positive definite");
            for pipelined in [false, true] {
                let fast = system
                    .solve_damped_with(lambda, pipelined)
                    .expect("positive definite");
                assert_eq!(fast.len(), plain.len());
                for (a, b) in fast.iter().zip(&plain) {
                    assert_eq!(a.to_bits(), b.to_bits(), "pipelined {pipelined}");
                }
            }
        }
        // Not positive definite at a node in the middle: both ways give up (the waiting
        // lane must not hang).
        for node in [150, 158] {
            let mut broken = system.clone();
            let r = 3 * node;
            let d = r - broken.first_col[r];
            broken.rows[r][d] = -1e9;
            assert!(solve_damped_plain(&broken, 1e-6).is_none());
            for pipelined in [false, true] {
                assert!(broken.solve_damped_with(1e-6, pipelined).is_none());
            }
        }
        graph.poses[1].x_m += 0.3;
        assert!(
            graph
                .optimize(&OptimizeOptions::default())
                .final_cost
                .is_finite()
        );
    }

    #[test]
    fn envelope_cholesky_solves_a_chain_with_a_long_edge() {
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
