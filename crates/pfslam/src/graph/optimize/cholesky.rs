//! The sparse block Cholesky factorisation of the normal equations: the symbolic
//! factorisation once per optimisation, the numeric one per damped solve.

use super::*;

/// The free nodes (1..n) in a fill-reducing order, the block structure of the Cholesky
/// factor it gives, and the buffers of the numeric factorisation, all reused across the
/// Levenberg-Marquardt iterations of one [`PoseGraph::optimize`] (the sparsity does not
/// change). Blocks are 3x3, row-major `[f64; 9]`.
pub(super) struct BlockCholesky {
    /// `perm[node - 1]` = position of the node in the factorisation.
    pub(super) perm: Vec<usize>,
    /// Column `j`'s off-diagonal blocks (rows below `j`) are `col_ptr[j]..col_ptr[j + 1]`.
    col_ptr: Vec<usize>,
    /// Block row of each off-diagonal block, ascending within a column.
    pub(super) row_idx: Vec<usize>,
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
    pub(super) fn new(n: usize, edges: &[Edge]) -> BlockCholesky {
        let m = n.saturating_sub(1);
        let (perm, lower) = permuted_lower_pattern(n, edges);
        let (col_ptr, row_idx) = factor_columns(&lower, m);
        let (row_ptr, row_entries) = factor_rows(&col_ptr, &row_idx, m);
        let pattern = FactorPattern {
            perm: &perm,
            col_ptr: &col_ptr,
            row_idx: &row_idx,
        };
        let edge_slots = edges.iter().map(|e| pattern.edge_slots(e, n)).collect();
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
    pub(super) fn step_of(&self, node: usize) -> [f64; 3] {
        let v = 3 * self.perm[node - 1];
        [self.x[v], self.x[v + 1], self.x[v + 2]]
    }

    /// Zeroes the normal equations.
    pub(super) fn clear(&mut self) {
        self.a_diag.fill([0.0; 9]);
        self.a_off.fill([0.0; 9]);
        self.rhs.fill(0.0);
    }

    /// Adds edge `k`'s blocks `h_ff`, `h_tt`, `h_tf` (rows of `to`, columns of `from`) and
    /// its gradients `g_f`, `g_t`; the fixed node's share is dropped.
    pub(super) fn add_edge(
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
    pub(super) fn solve_damped(&mut self, lambda: f64) -> bool {
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

/// Node `node`'s index among the free nodes (node 0 is fixed; `None` also past `n`).
fn free_node(node: usize, n: usize) -> Option<usize> {
    (node != 0 && node < n).then(|| node - 1)
}

/// The free nodes' positions in a fill-reducing order (`perm[node - 1]`), and the lower
/// pattern of the normal equations permuted by it, by column.
fn permuted_lower_pattern(n: usize, edges: &[Edge]) -> (Vec<usize>, Compressed) {
    let m = n.saturating_sub(1);
    let pairs = edges
        .iter()
        .filter_map(|e| match (free_node(e.from, n), free_node(e.to, n)) {
            (Some(a), Some(b)) if a != b => Some((a, b)),
            _ => None,
        });
    let adj = Compressed::from_pairs(m, pairs.flat_map(|(a, b)| [(a, b), (b, a)]));
    let order = postorder(&adj, &minimum_degree_order(&adj));
    let mut perm = vec![0; m];
    for (pos, &v) in order.iter().enumerate() {
        perm[v] = pos;
    }
    let mut lower_pairs = Vec::with_capacity(adj.idx.len() / 2);
    for v in 0..m {
        for &u in adj.row(v) {
            if perm[u] > perm[v] {
                lower_pairs.push((perm[v], perm[u]));
            }
        }
    }
    let lower = Compressed::from_pairs(m, lower_pairs.iter().copied());
    (perm, lower)
}

/// The factor's pattern by column (`col_ptr`, `row_idx`) from the permuted lower pattern:
/// column j holds its own entries and its elimination-tree children's entries below j.
fn factor_columns(lower: &Compressed, m: usize) -> (Vec<usize>, Vec<usize>) {
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
    (col_ptr, row_idx)
}

/// The factor's pattern by row (`row_ptr`, `row_entries`): the transpose of the columns,
/// each row's blocks by increasing column.
fn factor_rows(
    col_ptr: &[usize],
    row_idx: &[usize],
    m: usize,
) -> (Vec<usize>, Vec<(usize, usize)>) {
    let mut row_ptr = vec![0; m + 1];
    for &i in row_idx {
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
    (row_ptr, row_entries)
}

/// The order and column pattern of a factor, to find where an edge's blocks go.
struct FactorPattern<'a> {
    perm: &'a [usize],
    col_ptr: &'a [usize],
    row_idx: &'a [usize],
}

impl FactorPattern<'_> {
    /// The slot of the block at (`row`, `col`) below the diagonal, if in the pattern.
    fn slot(&self, row: usize, col: usize) -> Option<usize> {
        let range = self.col_ptr[col]..self.col_ptr[col + 1];
        self.row_idx[range.clone()]
            .binary_search(&row)
            .ok()
            .map(|k| range.start + k)
    }

    /// Where edge `e` of a graph with `n` nodes adds its blocks.
    fn edge_slots(&self, e: &Edge, n: usize) -> EdgeSlots {
        let (from, to) = (free_node(e.from, n), free_node(e.to, n));
        if e.from == e.to || e.from >= n || e.to >= n {
            // A self-edge's error does not depend on the poses.
            return EdgeSlots::default();
        }
        let (pf, pt) = (from.map(|v| self.perm[v]), to.map(|v| self.perm[v]));
        let off = match (pf, pt) {
            (Some(a), Some(b)) if b > a => self.slot(b, a).map(|s| (s, false)),
            (Some(a), Some(b)) => self.slot(a, b).map(|s| (s, true)),
            _ => None,
        };
        EdgeSlots {
            from: pf,
            to: pt,
            off,
        }
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
