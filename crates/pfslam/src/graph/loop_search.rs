//! A keyframe's loop searches: candidates verified, or taken from the batch verified ahead,
//! and the accepted closures added as loop edges.

use super::*;

impl BackEnd<'_> {
    /// The loop searches of keyframe `k` at `pose`: its candidates verified (or taken from
    /// the look-ahead), the accepted closures added as loop edges.
    pub(super) fn search_loops(&mut self, k: usize, pose: Pose2) {
        let (tried, verdicts) = self.loop_verdicts(k, pose);
        let opts = self.opts;
        let (graph, stats) = (&mut self.graph, &mut self.stats);
        stats.loop_candidates += tried.len();
        for (&j, checked) in tried.iter().zip(verdicts) {
            stats.loop_local += usize::from(checked.search != Search::Full);
            stats.loop_local_fallbacks += usize::from(checked.search == Search::LocalThenFull);
            match checked.verdict {
                Verdict::Accepted(found) => {
                    stats.loop_accepted += 1;
                    let z = graph.poses[j].between(&found);
                    let width = (opts.loops.kernel_width > 0.0).then_some(opts.loops.kernel_width);
                    graph.edges.push(Edge::with_sigmas(
                        j,
                        k,
                        z,
                        opts.loops.sigma_m,
                        opts.loops.sigma_deg.to_radians(),
                        width,
                    ));
                    self.loop_edges.push(graph.edges.len() - 1);
                    self.closures_pending = true;
                    if graph.edge_chi2(graph.edges.len() - 1) > opts.optimize.chi2 {
                        self.urgent = true;
                    }
                }
                Verdict::LowScore => stats.loop_rejected_score += 1,
                Verdict::Ambiguous => stats.loop_rejected_ambiguous += 1,
            }
        }
    }

    /// Keyframe `k`'s loop candidates and their verdicts: from the look-ahead when it holds
    /// them, else verified now in one parallel batch with the look-ahead's next jobs.
    fn loop_verdicts(&mut self, k: usize, pose: Pose2) -> (Vec<usize>, Vec<Checked>) {
        let opts = self.opts;
        let keyframes = self.keyframes;
        let generation = self.generation;
        let graph = &mut self.graph;
        // A look-ahead job computed before any optimisation since, at the same pose:
        // the same candidates (the earlier keyframes' poses are the same bits).
        let cached = match &mut self.ahead {
            Some(a) if a.generation == generation => a
                .jobs
                .iter()
                .position(|j| j.k == k && j.pose == pose)
                .map(|at| a.jobs.swap_remove(at)),
            _ => None,
        };
        match cached {
            Some(job) => (job.tried, job.verdicts),
            None => {
                let tried = loop_candidates(keyframes, &graph.poses, k, &pose, opts);
                if tried.is_empty() {
                    (tried, Vec::new())
                } else {
                    // The look-ahead's predicted poses go onto the graph's (removed
                    // after the batch): no copy of the whole path per batch.
                    let look_ahead = self.look_ahead;
                    let mut jobs = if !self.seq_matching && look_ahead > 1 {
                        // No periodic optimisation before `last_opt + every`: up to
                        // there the look-ahead cannot be overtaken by one.
                        let bound = self.last_opt + opts.optimize.every_keyframes;
                        let (searches, last) = if k < bound {
                            (look_ahead, bound)
                        } else {
                            (look_ahead.min(LOOK_AHEAD_UNBOUNDED), usize::MAX)
                        };
                        look_ahead_jobs(keyframes, &mut graph.poses, k, searches, last, opts)
                    } else {
                        Vec::new()
                    };
                    jobs.insert(
                        0,
                        AheadJob {
                            k,
                            pose,
                            tried: tried.clone(),
                            verdicts: Vec::new(),
                        },
                    );
                    let poses: &[Pose2] = &graph.poses;
                    // All independent: verified in parallel, collected in order.
                    let pairs: Vec<(usize, usize)> = jobs
                        .iter()
                        .enumerate()
                        .flat_map(|(a, job)| job.tried.iter().map(move |&j| (a, j)))
                        .collect();
                    // Whether a candidate is searched locally depends only on the last
                    // optimisation, which the look-ahead's verdicts are valid for.
                    let vouches = &self.vouches;
                    let (local_on, loop_win, local_win) =
                        (self.local_on, &self.loop_win, &self.local_win);
                    let found: Vec<Checked> = pairs
                        .par_iter()
                        .map(|&(a, j)| {
                            let job = &jobs[a];
                            let local = (local_on && vouches.vouch(keyframes, job.k, j, opts))
                                .then_some(local_win);
                            let pair = ClosurePair {
                                keyframe: job.k,
                                candidate: j,
                                pose: &job.pose,
                            };
                            verify_candidate(keyframes, poses, &pair, loop_win, local, opts)
                        })
                        .collect();
                    for (&(a, _), v) in pairs.iter().zip(found) {
                        jobs[a].verdicts.push(v);
                    }
                    graph.poses.truncate(k + 1);
                    let own = jobs.swap_remove(0).verdicts;
                    self.ahead = Some(LookAhead { generation, jobs });
                    (tried, own)
                }
            }
        }
    }
}
