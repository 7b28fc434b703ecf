//! The back end's driver: keyframes added one by one, optimisations when due, and the
//! final optimisation and corrected trajectory.

use super::*;

impl<'a> BackEnd<'a> {
    pub(super) fn new(
        recording: &'a Recording,
        trajectory: &'a [StampedPose2],
        opts: &'a GraphOptions,
        keyframes: &'a [Keyframe],
        look_ahead: usize,
    ) -> Self {
        let opt_opts = OptimizeOptions {
            max_iterations: opts.optimize.max_iterations,
            ..OptimizeOptions::default()
        };
        let periodic_opts = OptimizeOptions {
            relative_tolerance: opts.optimize.periodic_relative_tolerance,
            ..opt_opts
        };
        let seq_win = SearchWindow {
            xy_m: opts.sequential.window_m,
            yaw_rad: opts.sequential.window_deg.to_radians(),
            yaw_step_rad: opts.yaw_step_deg.to_radians(),
        };
        let loop_win = SearchWindow {
            xy_m: opts.loops.window_m,
            yaw_rad: opts.loops.window_deg.to_radians(),
            yaw_step_rad: seq_win.yaw_step_rad,
        };
        let local_win = SearchWindow {
            xy_m: opts.loops.local.window_m,
            yaw_rad: opts.loops.local.window_deg.to_radians(),
            yaw_step_rad: seq_win.yaw_step_rad,
        };
        // What the last optimisation vouches for (nothing before the first).
        let local_on = opts.loops.local.search.is_on(false);
        // `auto`: sequential matching for a level LiDAR fixed on the body (the recordings `auto`
        // runs `rbpf` on); odometry-yaw edges for a LiDAR fixed on the body.
        let level_and_fixed =
            crate::filter::FilterMode::Auto.resolve(recording) == crate::filter::FilterMode::Rbpf;
        let seq_matching = opts.sequential.matching.is_on(level_and_fixed);
        let yaw_edges = !seq_matching
            && opts.sequential.odometry_yaw_sigma_deg_per_sqrt_m > 0.0
            && opts
                .sequential
                .odometry_yaw_edges
                .is_on(recording.body_from_lidar_per_scan.is_none());
        BackEnd {
            recording,
            trajectory,
            opts,
            keyframes,
            look_ahead,
            opt_opts,
            periodic_opts,
            seq_win,
            loop_win,
            local_win,
            local_on,
            seq_matching,
            yaw_edges,
            stats: GraphStats::default(),
            graph: PoseGraph::default(),
            loop_edges: Vec::new(),
            vouches: Vouches::default(),
            closures_pending: false,
            urgent: false,
            last_opt: 0,
            submap_pts: Vec::new(),
            ahead: None,
            generation: 0,
            saved_prefix: 0,
        }
    }

    /// Adds keyframe `k` (after keyframes `0..k`): its sequential and odometry-yaw edges,
    /// its loop searches when due, and an optimisation when due.
    pub(super) fn add_keyframe(&mut self, k: usize) {
        let opts = self.opts;
        let kf = &self.keyframes[k];
        if k == 0 {
            self.graph.poses.push(kf.front_pose);
            return;
        }
        let t = Instant::now();
        let pose = self.add_sequential_edges(k);
        // Loop closures.
        let due =
            k.is_multiple_of(opts.loops.every_keyframes) && kf.points_body.len() >= opts.min_points;
        if due {
            self.search_loops(k, pose);
        }
        self.stats.matching_s += t.elapsed().as_secs_f64();
        self.maybe_optimize(k);
    }

    /// Optimises after keyframe `k` when a closure disagreed with the estimates, or when
    /// closures were accepted and `optimize.every_keyframes` passed since the last time.
    fn maybe_optimize(&mut self, k: usize) {
        let opts = self.opts;
        if self.urgent
            || (self.closures_pending && k - self.last_opt >= opts.optimize.every_keyframes)
        {
            let t = Instant::now();
            let last_opt = self.last_opt;
            let graph = &mut self.graph;
            let r = match self.urgent {
                true => graph.optimize(&self.opt_opts),
                // Keyframe 0 is always held: from keyframe 1 on is the whole graph.
                false
                    if opts.optimize.periodic_free_keyframes > 0
                        && last_opt > opts.optimize.periodic_free_keyframes + 1 =>
                {
                    let first = last_opt - opts.optimize.periodic_free_keyframes;
                    optimize_tail(graph, first, &self.periodic_opts)
                }
                false => graph.optimize(&self.periodic_opts),
            };
            self.generation += 1;
            if self.local_on {
                self.vouches = Vouches::after_optimisation(
                    &self.graph,
                    &self.loop_edges,
                    self.keyframes,
                    opts,
                );
            }
            self.stats.optimizations += 1;
            self.stats.iterations += r.iterations;
            self.stats.optimize_s += t.elapsed().as_secs_f64();
            self.closures_pending = false;
            self.urgent = false;
            self.last_opt = k;
        }
    }

    /// The final optimisation, outlier removal and again; every scan's corrected pose
    /// (refined when `refine.scans` is on).
    pub(super) fn finish(
        self,
        scan_opts: &ScanOptions,
        t_start: Instant,
    ) -> Result<GraphResult, GraphError> {
        let BackEnd {
            recording,
            trajectory,
            opts,
            keyframes,
            opt_opts,
            mut stats,
            mut graph,
            loop_edges,
            ..
        } = self;
        // Final optimisation, outlier removal, again.
        let t = Instant::now();
        let r = graph.optimize(&opt_opts);
        stats.optimizations += 1;
        stats.iterations += r.iterations;
        let outliers: Vec<usize> = loop_edges
            .iter()
            .copied()
            .filter(|&e| graph.edge_chi2(e) > opts.loops.outlier_chi2)
            .collect();
        if !outliers.is_empty() {
            stats.loop_removed_outliers = outliers.len();
            let mut keep = vec![true; graph.edges.len()];
            for &e in &outliers {
                keep[e] = false;
            }
            let mut idx = 0;
            graph.edges.retain(|_| {
                idx += 1;
                keep[idx - 1]
            });
            let r = graph.optimize(&opt_opts);
            stats.optimizations += 1;
            stats.iterations += r.iterations;
        }
        stats.final_cost = graph.cost();
        stats.optimize_s += t.elapsed().as_secs_f64();
        stats.nodes = graph.poses.len();
        stats.edges = graph.edges.len();
        let loop_pairs = graph
            .edges
            .iter()
            .filter(|e| e.to != e.from + 1)
            .map(|e| (e.from, e.to))
            .collect();
        let t = Instant::now();
        let closed = stats.loop_accepted > stats.loop_removed_outliers;
        // Without a surviving closure the back end would only re-match scans (on the
        // simulated car with sequential matching on, that drifted to 6.7 m): the front
        // end's trajectory is kept as it is.
        if !closed {
            graph.poses = keyframes.iter().map(|kf| kf.front_pose).collect();
        }
        let mut out = correct_trajectory(trajectory, keyframes, &graph.poses);
        if opts.refine.scans.is_on(true) && closed {
            refine_scans(
                recording,
                scan_opts,
                trajectory,
                keyframes,
                &graph.poses,
                opts,
                &mut out,
            )?;
        }
        stats.refine_s = t.elapsed().as_secs_f64();
        let kf_out = keyframes
            .iter()
            .zip(&graph.poses)
            .map(|(kf, p)| StampedPose2 {
                stamp_ns: trajectory[kf.traj_index].stamp_ns,
                pose: *p,
            })
            .collect();
        stats.total_s = t_start.elapsed().as_secs_f64();
        Ok(GraphResult {
            trajectory: out,
            keyframes: kf_out,
            loop_edges: loop_pairs,
            stats,
        })
    }
}

/// Optimises keyframes `first..` of `graph` (`first >= 1`) with the earlier ones held
/// fixed: a graph of those keyframes behind a fixed origin, each edge from a fixed keyframe
/// re-anchored at the origin (its measurement composed with the fixed pose: the same
/// error), edges between fixed keyframes left out (their error cannot change). Every edge
/// here runs from an earlier keyframe to a later one; should one run backwards into the
/// fixed part, the whole graph is optimised instead.
pub(super) fn optimize_tail(
    graph: &mut PoseGraph,
    first: usize,
    opts: &OptimizeOptions,
) -> optimize::OptimizeReport {
    if first >= graph.poses.len() || graph.edges.iter().any(|e| e.from >= first && e.to < first) {
        return graph.optimize(opts);
    }
    let mut tail = PoseGraph {
        poses: Vec::with_capacity(graph.poses.len() - first + 1),
        edges: Vec::new(),
    };
    tail.poses.push(Pose2::IDENTITY);
    tail.poses.extend_from_slice(&graph.poses[first..]);
    let at = |v: usize| v + 1 - first;
    for e in graph.edges.iter().filter(|e| e.to >= first) {
        tail.edges.push(match e.from >= first {
            true => Edge {
                from: at(e.from),
                to: at(e.to),
                ..*e
            },
            false => Edge {
                from: 0,
                to: at(e.to),
                measurement: graph.poses[e.from].compose(&e.measurement),
                ..*e
            },
        });
    }
    let r = tail.optimize(opts);
    graph.poses[first..].copy_from_slice(&tail.poses[1..]);
    r
}
