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

mod cholesky;
mod ordering;

use cholesky::BlockCholesky;
use ordering::{Compressed, minimum_degree_order, postorder};

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

#[cfg(test)]
mod tests;
