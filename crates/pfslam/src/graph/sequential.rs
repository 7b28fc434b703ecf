//! The edges from a keyframe to the one before it: a sequential match, the front end's
//! relative motion and the odometry's yaw.

use super::*;

impl BackEnd<'_> {
    /// Keyframe `k`'s pose and the edges to keyframe `k - 1`: a sequential match (with the
    /// front end's relative motion beside it) or the front end's relative motion alone,
    /// and the odometry-yaw edge. Returns the pose.
    pub(super) fn add_sequential_edges(&mut self, k: usize) -> Pose2 {
        let opts = self.opts;
        let rel_front = self.keyframes[k - 1]
            .front_pose
            .between(&self.keyframes[k].front_pose);
        let predicted = self.graph.poses[k - 1].compose(&rel_front);
        if self.keyframes[k].traj_index < self.saved_prefix {
            // A saved session's keyframes keep their relative poses (the result of that
            // session's back end): consecutive ones may be far apart, where the revisits
            // between them were not saved, so matching them in sequence means nothing.
            let edge = self.chained_edge(k, rel_front);
            self.graph.poses.push(predicted);
            self.graph.edges.push(edge);
            return predicted;
        }
        let matched = self.match_sequential(k, &predicted);
        let front_edge = self.front_end_edge(k, rel_front);
        let (graph, stats) = (&mut self.graph, &mut self.stats);
        let (pose, edge) = match matched {
            Some((pose, curv)) => {
                stats.sequential_matched += 1;
                let z = graph.poses[k - 1].between(&pose);
                let e = Edge {
                    from: k - 1,
                    to: k,
                    measurement: z,
                    information: capped_information(
                        &curv,
                        pose.yaw_rad,
                        opts.sequential.sigma_m,
                        opts.sequential.sigma_deg.to_radians(),
                    ),
                    robust_width: None,
                };
                graph.edges.push(front_edge);
                (pose, e)
            }
            None if self.seq_matching => {
                stats.sequential_fallback += 1;
                (predicted, front_edge)
            }
            None => {
                stats.sequential_front_end += 1;
                (predicted, front_edge)
            }
        };
        graph.poses.push(pose);
        graph.edges.push(edge);
        if self.yaw_edges {
            self.add_odometry_yaw_edge(k);
        }
        pose
    }

    /// Keyframe `k` matched against the previous keyframes' submap around `predicted`: the
    /// pose and the score's curvature there, or `None` when sequential matching is off, the
    /// keyframe has too few points or the match scores too low.
    fn match_sequential(
        &mut self,
        k: usize,
        predicted: &Pose2,
    ) -> Option<(Pose2, nalgebra::Matrix3<f64>)> {
        let opts = self.opts;
        let keyframes = self.keyframes;
        let seq_win = &self.seq_win;
        let kf = &keyframes[k];
        let first = k.saturating_sub(opts.sequential.submap_keyframes);
        gather_points(keyframes, &self.graph.poses, first..k, &mut self.submap_pts);
        let submap_pts = &self.submap_pts;
        let margin = opts.sequential.window_m + 3.0 * opts.field_sigma_m + opts.resolution_m;
        let bounds = bounds_around(&kf.points_body, predicted, margin)
            .and_then(|b| clip_to_points(b, submap_pts, 3.0 * opts.field_sigma_m));
        let enough = self.seq_matching && kf.points_body.len() >= opts.min_points;
        bounds.filter(|_| enough).and_then(|(lo, hi)| {
            let field =
                PointField::build(submap_pts, lo, hi, opts.resolution_m, opts.field_sigma_m, 0);
            let prior = Prior {
                pose: *predicted,
                sigma_xy_m: opts.sequential.prior_sigma_m,
                sigma_yaw_rad: opts.sequential.prior_sigma_deg.to_radians(),
            };
            let coarse = field.search_with_prior(&kf.points_body, &prior, seq_win);
            let (pose, score) = field.refine(
                &kf.points_body,
                &coarse,
                seq_win.yaw_step_rad,
                4,
                Some(&prior),
            );
            (score >= opts.sequential.min_score).then(|| {
                let curv = field.curvature(
                    &kf.points_body,
                    &pose,
                    0.5 * opts.resolution_m,
                    seq_win.yaw_step_rad,
                );
                (pose, curv)
            })
        })
    }

    /// The edge of the front end's relative motion `rel_front` from keyframe `k - 1` to `k`.
    /// It always constrains the pair (weakly): where the match pins nothing down (along a
    /// corridor) it decides. Without sequential matching it is the only edge, with its
    /// random-walk uncertainty.
    fn front_end_edge(&self, k: usize, rel_front: Pose2) -> Edge {
        let opts = self.opts;
        if !self.seq_matching {
            return self.chained_edge(k, rel_front);
        }
        let (sigma_m, sigma_deg) = (
            opts.sequential.fallback_sigma_m,
            opts.sequential.fallback_sigma_deg,
        );
        Edge::with_sigmas(k - 1, k, rel_front, sigma_m, sigma_deg.to_radians(), None)
    }

    /// The front end's motion from keyframe `k - 1` to `k` as an edge whose sigmas grow with
    /// the square root of the distance (`front_end_sigma_*_per_sqrt_m`).
    fn chained_edge(&self, k: usize, rel_front: Pose2) -> Edge {
        let opts = self.opts;
        let root = rel_front.translation_norm_m().max(0.01).sqrt();
        let sigma_m = opts.sequential.front_end_sigma_m_per_sqrt_m * root;
        let sigma_rad = (opts.sequential.front_end_sigma_deg_per_sqrt_m * root).to_radians();
        Edge::with_sigmas(k - 1, k, rel_front, sigma_m, sigma_rad, None)
    }

    /// The odometry's yaw change from keyframe `k - 1` to `k` as an edge, when the odometry
    /// covers both.
    fn add_odometry_yaw_edge(&mut self, k: usize) {
        let opts = self.opts;
        let (prev, kf) = (&self.keyframes[k - 1], &self.keyframes[k]);
        let odo = &self.recording.odometry;
        let trajectory = self.trajectory;
        let stamp = |kf: &Keyframe| trajectory[kf.traj_index].stamp_ns;
        if let (Some(a), Some(b)) = (odo.pose_at(stamp(prev)), odo.pose_at(stamp(kf))) {
            // Yaw only: the x/y standard deviation is far beyond any error.
            let z = a.between(&b);
            let root = z.translation_norm_m().max(0.01).sqrt();
            let sigma_yaw_deg = opts.sequential.odometry_yaw_sigma_deg_per_sqrt_m * root;
            self.graph.edges.push(Edge::with_sigmas(
                k - 1,
                k,
                z,
                1e3,
                sigma_yaw_deg.to_radians(),
                None,
            ));
            self.stats.odometry_yaw_edges += 1;
        }
    }
}

/// The information of a match edge: the match's curvature (world x, y, yaw) in the edge's
/// error frame (rotated into the matched pose's frame), its eigenvalues capped, after
/// whitening by `sigma_xy_m` / `sigma_yaw_rad`, at 1 (no direction more certain than those
/// standard deviations) and floored at 0.
fn capped_information(
    curvature_world: &nalgebra::Matrix3<f64>,
    yaw_rad: f64,
    sigma_xy_m: f64,
    sigma_yaw_rad: f64,
) -> nalgebra::Matrix3<f64> {
    let (s, c) = yaw_rad.sin_cos();
    let r = nalgebra::Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
    let local = r.transpose() * curvature_world * r;
    let w = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(
        sigma_xy_m,
        sigma_xy_m,
        sigma_yaw_rad,
    ));
    let m = w * local * w;
    let m = (m + m.transpose()) * 0.5;
    let eig = m.symmetric_eigen();
    let capped = eig.eigenvalues.map(|v| v.clamp(0.0, 1.0));
    let m =
        eig.eigenvectors * nalgebra::Matrix3::from_diagonal(&capped) * eig.eigenvectors.transpose();
    let winv = w.try_inverse().unwrap_or_else(nalgebra::Matrix3::identity);
    winv * m * winv
}
