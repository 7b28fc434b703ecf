//! The fill-reducing elimination order of the free nodes: minimum degree on the quotient
//! graph, then a postorder of the elimination tree.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// A graph or a sparsity pattern in compressed rows: row `i` is `idx[ptr[i]..ptr[i + 1]]`.
pub(super) struct Compressed {
    pub(super) ptr: Vec<usize>,
    pub(super) idx: Vec<usize>,
}

impl Compressed {
    /// From `(row, column)` pairs; each row sorted, without duplicates.
    pub(super) fn from_pairs(
        rows: usize,
        pairs: impl Iterator<Item = (usize, usize)> + Clone,
    ) -> Compressed {
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

    pub(super) fn row(&self, i: usize) -> &[usize] {
        &self.idx[self.ptr[i]..self.ptr[i + 1]]
    }
}

/// A minimum-degree elimination order of a graph without self-loops (`order[k]` = the k-th
/// node eliminated): on the quotient graph, with AMD's approximate external degrees and
/// element absorption (Amestoy, Davis and Duff 1996), without supervariables (the nodes
/// are already 3x3 blocks). Ties go to the lowest index, so the order depends only on the
/// graph.
pub(super) fn minimum_degree_order(adj: &Compressed) -> Vec<usize> {
    let mut graph = QuotientGraph::new(adj);
    let m = graph.state.len();
    // Stale entries (an old degree, or eliminated) are skipped when popped.
    let mut queue: BinaryHeap<Reverse<(usize, usize)>> =
        (0..m).map(|i| Reverse((graph.degree[i], i))).collect();
    let mut order = Vec::with_capacity(m);
    while let Some(Reverse((d, p))) = queue.pop() {
        if graph.state[p] != State::Variable || d != graph.degree[p] {
            continue;
        }
        let step = order.len();
        order.push(p);
        let remaining = m - order.len();
        graph.eliminate(p, step);
        graph.count_outside(p, step);
        graph.update_variables(p, step, remaining, &mut queue);
    }
    order
}

/// What a node of the quotient graph is.
#[derive(Clone, Copy, PartialEq)]
enum State {
    Variable,
    Element,
    Absorbed,
}

/// Marks "not in any step".
const NONE: usize = usize::MAX;

/// The quotient graph of [`minimum_degree_order`]: the variables not yet eliminated, the
/// elements the eliminated ones became, and the degrees.
struct QuotientGraph<'a> {
    state: Vec<State>,
    /// A variable's variable neighbours: `vars[vars_at[i]..][..vars_len[i]]`, only shrinking.
    vars: Vec<usize>,
    vars_at: &'a [usize],
    vars_len: Vec<usize>,
    /// A variable's adjacent elements.
    elems: Vec<Vec<usize>>,
    /// An element's variables: `members[members_at[e]..][..members_len[e]]` (fixed once
    /// made: an element holding an eliminated variable has been absorbed).
    members: Vec<usize>,
    members_at: Vec<usize>,
    members_len: Vec<usize>,
    degree: Vec<usize>,
    /// The step at which a variable joined the newest element (`NONE`: never).
    in_lp: Vec<usize>,
    /// The step at which `w[e]` was last reset.
    w_step: Vec<usize>,
    /// `|Le \ Lp|` of element `e` during the current step.
    w: Vec<usize>,
}

impl<'a> QuotientGraph<'a> {
    /// Every node a variable, with its neighbours in `adj`.
    fn new(adj: &'a Compressed) -> Self {
        let m = adj.ptr.len() - 1;
        let vars_len: Vec<usize> = (0..m).map(|i| adj.ptr[i + 1] - adj.ptr[i]).collect();
        QuotientGraph {
            state: vec![State::Variable; m],
            vars: adj.idx.clone(),
            vars_at: &adj.ptr,
            degree: vars_len.clone(),
            vars_len,
            elems: vec![Vec::new(); m],
            members: Vec::new(),
            members_at: vec![0; m],
            members_len: vec![0; m],
            in_lp: vec![NONE; m],
            w_step: vec![NONE; m],
            w: vec![0usize; m],
        }
    }

    /// Turns variable `p` into the element `Lp` of step `step`: its variables and those of
    /// the elements it absorbs.
    fn eliminate(&mut self, p: usize, step: usize) {
        let lp_at = self.members.len();
        self.in_lp[p] = step;
        for &v in &self.vars[self.vars_at[p]..][..self.vars_len[p]] {
            if self.in_lp[v] != step {
                self.in_lp[v] = step;
                self.members.push(v);
            }
        }
        for &e in &self.elems[p] {
            if self.state[e] != State::Element {
                continue;
            }
            for k in self.members_at[e]..self.members_at[e] + self.members_len[e] {
                let v = self.members[k];
                if self.in_lp[v] != step {
                    self.in_lp[v] = step;
                    self.members.push(v);
                }
            }
            self.state[e] = State::Absorbed;
        }
        self.state[p] = State::Element;
        self.vars_len[p] = 0;
        self.elems[p] = Vec::new();
        self.members_at[p] = lp_at;
        self.members_len[p] = self.members.len() - lp_at;
    }

    /// `|Le \ Lp|` of every other element next to the element `p` just made.
    fn count_outside(&mut self, p: usize, step: usize) {
        let lp = &self.members[self.members_at[p]..][..self.members_len[p]];
        for &i in lp {
            for &e in &self.elems[i] {
                if self.state[e] != State::Element {
                    continue;
                }
                if self.w_step[e] != step {
                    self.w_step[e] = step;
                    self.w[e] = self.members_len[e];
                }
                self.w[e] -= 1;
            }
        }
    }

    /// The variables of the element `p` just made: elements inside it absorbed, variables
    /// in it reached through it, approximate degrees lowered (and queued when changed).
    fn update_variables(
        &mut self,
        p: usize,
        step: usize,
        remaining: usize,
        queue: &mut BinaryHeap<Reverse<(usize, usize)>>,
    ) {
        let QuotientGraph {
            state,
            vars,
            vars_at,
            vars_len,
            elems,
            members,
            members_at,
            members_len,
            degree,
            in_lp,
            w,
            ..
        } = self;
        let lp = &members[members_at[p]..][..members_len[p]];
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
}

/// `order` (an elimination order of `adj`) rearranged into a postorder of its elimination
/// tree (children by increasing position): the same factor pattern, but each subtree's
/// columns are contiguous, so the columns that update a column were computed recently.
pub(super) fn postorder(adj: &Compressed, order: &[usize]) -> Vec<usize> {
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
