//! The noise of the three measurements of each step between consecutive keyframes (the
//! odometry, the front end's motion, the sequential match), measured from how they disagree:
//! with independent errors the variance of a pairwise difference is the sum of the two
//! variances, so three pairs give each one's own (the "three-cornered hat"). The odometry
//! then ties the steps as well as it deserves: firmly where it is exact, hardly where it is
//! poor. Off by default: `docs/decisions/0052-odometry-edges-from-the-chains-agreement.md`.

use super::keyframes::Keyframe;
use super::optimize::{Edge, PoseGraph};
use crate::geometry::{Pose2, StampedPose2, wrap_angle};
use crate::sensors::Recording;
use serde::Serialize;

/// The edges from keyframe `k - 1` to `k` (indices into the graph's edges).
#[derive(Debug, Clone, Copy)]
pub(super) struct ChainStep {
    /// The front end's relative motion.
    pub front_edge: usize,
    /// The sequential match, when one succeeded.
    pub seq_edge: Option<usize>,
}

/// Standard deviations per step of each chain (x/y per axis in m, yaw in rad).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StepNoise {
    /// Steps with all three measurements.
    pub steps: usize,
    /// The odometry's (m, rad).
    pub odometry: [f64; 2],
    /// The front end's relative motion's.
    pub front_end: [f64; 2],
    /// The sequential matches'.
    pub sequential: [f64; 2],
}

/// Steps needed for the medians to mean something.
const MIN_STEPS: usize = 50;
/// Smallest standard deviations given to any chain (m, rad): a chain that agrees with
/// another to the last digit must not become rigid.
const MIN_SIGMA: [f64; 2] = [0.002, 0.0005];
/// Consistency factor of the median absolute deviation for a normal distribution.
const MAD_TO_SIGMA: f64 = 1.4826;

/// The odometry's motion between consecutive keyframes (`None` where it does not cover
/// both stamps), indexed like the chain (`k - 1` for the step into `k`).
pub(super) fn odometry_steps(
    recording: &Recording,
    trajectory: &[StampedPose2],
    keyframes: &[Keyframe],
) -> Vec<Option<Pose2>> {
    let at = |kf: &Keyframe| {
        recording
            .odometry
            .pose_at(trajectory[kf.traj_index].stamp_ns)
    };
    keyframes
        .windows(2)
        .map(|w| Some(at(&w[0])?.between(&at(&w[1])?)))
        .collect()
}

/// Measures the three chains' noise over the steps where all three exist, then adds the
/// odometry's steps as edges with its noise (the front end's and the matches' edges keep
/// their sigmas: their errors are correlated, both being scan matches, so their own
/// estimates are not trusted). `None` (graph unchanged) with fewer than [`MIN_STEPS`]
/// such steps.
pub(super) fn add_odometry_edges(
    graph: &mut PoseGraph,
    chain: &[ChainStep],
    odometry: &[Option<Pose2>],
) -> Option<StepNoise> {
    let mut triples = Vec::new();
    for (s, odo) in chain.iter().zip(odometry) {
        if let (Some(seq), Some(odo)) = (s.seq_edge, odo) {
            let front = graph.edges[s.front_edge].measurement;
            triples.push((*odo, front, graph.edges[seq].measurement));
        }
    }
    if triples.len() < MIN_STEPS {
        return None;
    }
    let noise = three_cornered_hat(&triples);
    let [sxy, syaw] = noise.odometry;
    for (k, odo) in odometry.iter().enumerate() {
        if let Some(odo) = odo {
            graph
                .edges
                .push(Edge::with_sigmas(k, k + 1, *odo, sxy, syaw, None));
        }
    }
    Some(noise)
}

/// Each chain's standard deviations from the robust variances of the three pairwise
/// differences of `(odometry, front end, sequential)` steps, per step. Measured also over
/// runs of 4 and 16 consecutive steps: where a chain's variance grows faster than the
/// number of steps (a bias: an odometry's scale or yaw-rate error), its per-step variance
/// is that growth's, since independent per-step edges would let the bias add up unchecked.
fn three_cornered_hat(triples: &[(Pose2, Pose2, Pose2)]) -> StepNoise {
    let mut worst = [[0.0f64; 2]; 3];
    for n in [1usize, 4, 16] {
        let runs: Vec<(Pose2, Pose2, Pose2)> = triples
            .chunks_exact(n)
            .map(|c| {
                c.iter().fold(
                    (Pose2::default(), Pose2::default(), Pose2::default()),
                    |acc, t| {
                        (
                            acc.0.compose(&t.0),
                            acc.1.compose(&t.1),
                            acc.2.compose(&t.2),
                        )
                    },
                )
            })
            .collect();
        if runs.len() < MIN_STEPS / 2 {
            break;
        }
        let var = |pick: fn(&(Pose2, Pose2, Pose2)) -> (Pose2, Pose2)| -> [f64; 2] {
            let mut xy = Vec::with_capacity(2 * runs.len());
            let mut yaw = Vec::with_capacity(runs.len());
            for t in &runs {
                let (a, b) = pick(t);
                let d = a.between(&b);
                xy.push(d.x_m);
                xy.push(d.y_m);
                yaw.push(wrap_angle(d.yaw_rad));
            }
            [robust_var(xy), robust_var(yaw)]
        };
        let of = var(|t| (t.0, t.1));
        let os = var(|t| (t.0, t.2));
        let fs = var(|t| (t.1, t.2));
        let solve =
            |a: [f64; 2], b: [f64; 2], c: [f64; 2]| [0, 1].map(|i| 0.5 * (a[i] + b[i] - c[i]));
        for (w, v) in
            worst
                .iter_mut()
                .zip([solve(of, os, fs), solve(of, fs, os), solve(os, fs, of)])
        {
            for i in 0..2 {
                w[i] = w[i].max(v[i] / n as f64);
            }
        }
    }
    let sigma = |v: [f64; 2]| [0, 1].map(|i| v[i].max(MIN_SIGMA[i] * MIN_SIGMA[i]).sqrt());
    StepNoise {
        steps: triples.len(),
        odometry: sigma(worst[0]),
        front_end: sigma(worst[1]),
        sequential: sigma(worst[2]),
    }
}

/// The variance of `v` from its median absolute deviation (robust to a few gross errors).
fn robust_var(v: Vec<f64>) -> f64 {
    // About zero, not the median: a bias (an odometry's scale or yaw-rate error) is noise
    // to the graph, which takes every edge as unbiased.
    let mad = median(v.into_iter().map(f64::abs).collect());
    (MAD_TO_SIGMA * mad).powi(2)
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Three chains with known independent noise: the hat recovers each one's sigma, and a
    /// biased odometry is charged its bias.
    #[test]
    fn three_cornered_hat_recovers_each_chains_noise() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
        let step =
            |rng: &mut rand_xoshiro::Xoshiro256PlusPlus, s_xy: f64, s_yaw: f64, bias: f64| {
                let (n, a) = (
                    Normal::new(0.0, s_xy).unwrap(),
                    Normal::new(bias, s_yaw).unwrap(),
                );
                Pose2::new(0.3 + n.sample(rng), n.sample(rng), a.sample(rng))
            };
        let run = |rng: &mut rand_xoshiro::Xoshiro256PlusPlus, bias: f64| {
            let triples: Vec<_> = (0..4000)
                .map(|_| {
                    (
                        step(rng, 0.004, 0.001, bias),
                        step(rng, 0.02, 0.004, 0.0),
                        step(rng, 0.01, 0.002, 0.0),
                    )
                })
                .collect();
            three_cornered_hat(&triples)
        };
        let n = run(&mut rng, 0.0);
        // The largest of three window estimates: conservative, so up to 40 % above (the
        // yaw noise of long runs also moves their ends sideways), never far below.
        let near = |got: f64, want: f64| (0.85..1.4).contains(&(got / want));
        assert!(
            near(n.odometry[0], 0.004) && near(n.odometry[1], 0.001),
            "{n:?}"
        );
        assert!(
            near(n.front_end[0], 0.02) && near(n.front_end[1], 0.004),
            "{n:?}"
        );
        assert!(
            near(n.sequential[0], 0.01) && near(n.sequential[1], 0.002),
            "{n:?}"
        );
        // A yaw bias of 2 mrad per step adds up over 16 steps: the odometry's yaw sigma
        // takes that growth, far above its 1 mrad of noise.
        let b = run(&mut rng, 0.002);
        assert!(b.odometry[1] > 0.005, "{b:?}");
    }
}
