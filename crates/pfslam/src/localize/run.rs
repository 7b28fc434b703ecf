//! The localisation loop over a recording: move the particles by the odometry between
//! updates, update once the robot moved enough, and output a pose at every scan (the last
//! estimate moved on by the odometry).

use super::estimate::{ClusterShape, Estimate, estimate};
use super::kld::KldBins;
use super::mcl::{FreeSpace, ParticleSet, ResamplePlan, Streams};
use super::{LocalizeError, LocalizeOptions};
use crate::geometry::{Pose2, StampedPose2, wrap_angle};
use crate::map::{BinaryMap, PlanarScan, ScanOptions, ScanProjector};
use crate::matching::map_field::{FieldModel, LikelihoodField, Sharpness, refine_pose, track_pose};
use crate::motion::odometry_model::{OdometryModel, OdometryModelOptions};
use crate::motion::odometry_timing::{OdometryTimingReport, run_timed};
use crate::sensors::Recording;
use crate::sensors::stale::StaleScans;
use serde::Serialize;

/// One filter update.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct UpdateRecord {
    /// The scan's stamp (ns).
    pub stamp_ns: i64,
    /// Particles weighed.
    pub particles: usize,
    /// Particles drawn at random over the free space by the resampling that followed.
    pub injected: usize,
    /// The heaviest cluster's share of the weight.
    pub mass: f64,
    /// Geometric mean likelihood of a return over the particles.
    pub fit: f64,
    /// Geometric mean likelihood of the best-fitting `core_share` of the returns at the
    /// estimate (the fit augmented MCL tracks; [`crate::localize::RecoveryOptions`]).
    pub core_fit: f64,
    /// The heaviest cluster held `converged_mass` of the weight: the filter tracks one place
    /// (else it searches, with the broad likelihood).
    pub converged: bool,
    /// Share of this scan's returns far from every wall at the estimate
    /// ([`LocalizeResult::off_wall_share`]).
    pub off_wall_share: f64,
}

/// What a localisation run produced.
#[derive(Debug, Clone)]
pub struct LocalizeResult {
    /// A pose at every scan from the first inside the odometry's span.
    pub trajectory: Vec<StampedPose2>,
    /// Every update.
    pub updates: Vec<UpdateRecord>,
    /// Scans outside the odometry's time span (no pose).
    pub scans_outside_odometry: usize,
    /// Scans without a return after preprocessing (pose carried by the odometry).
    pub scans_without_returns: usize,
    /// Stale scans left out (no pose; [`crate::sensors::stale`]).
    pub scans_stale: usize,
    /// Share of the returns at the update poses farther than three `sigma_hit_m` from the
    /// nearest occupied cell: returns the map does not explain (a wrong pose, or things not
    /// in the map). Unlike the share in free cells, it does not count the returns a
    /// centimetre beside a one-cell wall.
    pub off_wall_share: f64,
}

impl LocalizeResult {
    /// The trajectory from the start of the final convergence (empty when it never settled).
    pub fn converged_part(&self) -> &[StampedPose2] {
        let Some(from) = self.converged_from_ns() else {
            return &[];
        };
        let first = self.trajectory.partition_point(|p| p.stamp_ns < from);
        &self.trajectory[first..]
    }

    /// The stamp of the update from which the filter stayed converged to the end (`None`
    /// when it was not converged at the end).
    pub fn converged_from_ns(&self) -> Option<i64> {
        let last_unconverged = self.updates.iter().rposition(|u| !u.converged);
        match last_unconverged {
            Some(k) => self.updates.get(k + 1).map(|u| u.stamp_ns),
            None => self.updates.first().map(|u| u.stamp_ns),
        }
    }

    /// The stamp of the first update at which the filter counted itself converged.
    pub fn first_converged_ns(&self) -> Option<i64> {
        self.updates
            .iter()
            .find(|u| u.converged)
            .map(|u| u.stamp_ns)
    }

    /// The number of times a converged filter lost its convergence.
    pub fn convergence_losses(&self) -> usize {
        self.updates
            .windows(2)
            .filter(|w| w[0].converged && !w[1].converged)
            .count()
    }
}

/// [`localize`] with the odometry's timing handled as a SLAM run does
/// ([`crate::motion::odometry_timing::run_timed`]): shifted by `shift_s` when set
/// (`[input] odometry_shift_s`), else run again on the odometry shifted by the lag measured
/// on the converged part of a first run, when that lag is notable.
pub fn localize_timed(
    recording: &Recording,
    map: &BinaryMap,
    options: &LocalizeOptions,
    scan_options: &ScanOptions,
    initial_pose: Option<Pose2>,
    seed: u64,
    shift_s: Option<f64>,
) -> Result<(LocalizeResult, OdometryTimingReport), LocalizeError> {
    crate::sensors::reader_options::check_odometry_shift(shift_s).map_err(LocalizeError::Shift)?;
    let once = |rec: &Recording, _| localize(rec, map, options, scan_options, initial_pose, seed);
    run_timed(recording, shift_s, once, |r: &LocalizeResult| {
        r.converged_part()
    })
}

/// Localises `recording` in `map`: from `initial_pose` (world frame of the map) when given,
/// else globally over the map's free space.
pub fn localize(
    recording: &Recording,
    map: &BinaryMap,
    options: &LocalizeOptions,
    scan_options: &ScanOptions,
    initial_pose: Option<Pose2>,
    seed: u64,
) -> Result<LocalizeResult, LocalizeError> {
    options.validate().map_err(LocalizeError::Options)?;
    let free = FreeSpace::new(map).ok_or(LocalizeError::NoFreeSpace)?;
    let scans = &recording.scans;
    let first = (0..scans.len())
        .find(|&i| recording.odometry.pose_at(scans.stamps_ns[i]).is_some())
        .ok_or_else(|| LocalizeError::Input {
            name: recording.name.clone(),
            message: "no scan lies within the odometry's time span".into(),
        })?;
    let field = LikelihoodField::new(
        map,
        &FieldModel {
            sigma_hit_m: [
                options.likelihood.sigma_hit_m,
                options.likelihood.global_sigma_hit_m,
            ],
            z_hit: options.likelihood.z_hit,
            max_distance_m: options.likelihood.max_distance_m,
            range_max_m: recording.lidar.range_max_m as f64,
        },
    );
    let projector = ScanProjector::new(
        &recording.lidar,
        &recording.body_from_lidar,
        &ScanOptions {
            densify_max_gap_m: None,
            ..*scan_options
        },
    )?;
    let mut state = State::new(options, &free, initial_pose, seed);
    let mut out = Outputs::default();
    let mut stale = StaleScans::default();
    let mut io = ScanIo {
        projector,
        body: PlanarScan::default(),
        points: Vec::new(),
    };
    for i in first..scans.len() {
        let stamp_ns = scans.stamps_ns[i];
        let Some(odom) = recording.odometry.pose_at(stamp_ns) else {
            out.scans_outside_odometry += 1;
            continue;
        };
        if stale.check(stamp_ns, scans.ranges(i), recording.lidar_at(i), &odom) {
            out.scans_stale += 1;
            continue;
        }
        let update = state.wants_update(&odom);
        if update {
            io.projector.aim(recording, i);
            io.projector.to_body(scans.ranges(i), &mut io.body)?;
            io.select(options.likelihood.max_beams);
            if io.points.is_empty() {
                out.scans_without_returns += 1;
            } else {
                let mut record = state.update(&field, &free, &io.points, stamp_ns, &odom);
                if state.converged && options.refine_estimate {
                    io.all_hits();
                    state.refine(&field, &io.points);
                }
                let reach_m = 3.0 * options.likelihood.sigma_hit_m;
                record.off_wall_share =
                    out.count_off_wall(&field, reach_m, &state.estimate.pose, &io.body);
                out.updates.push(record);
            }
        }
        let mut pose = state.pose_at(&odom);
        if !update && state.converged && options.refine_estimate {
            pose = io.refined(recording, i, &field, &pose)?;
        }
        out.trajectory.push(StampedPose2 { stamp_ns, pose });
    }
    out.scans_outside_odometry += first;
    Ok(out.finish())
}

/// Reused scan buffers.
struct ScanIo {
    projector: ScanProjector,
    body: PlanarScan,
    points: Vec<[f64; 2]>,
}

impl ScanIo {
    /// `pose` of scan `i` between updates refined by matching every return in the field
    /// (the particles stay): the odometry composed since the last update drifts, most
    /// while turning.
    fn refined(
        &mut self,
        recording: &Recording,
        i: usize,
        field: &LikelihoodField,
        pose: &Pose2,
    ) -> Result<Pose2, LocalizeError> {
        self.projector.aim(recording, i);
        self.projector
            .to_body(recording.scans.ranges(i), &mut self.body)?;
        self.all_hits();
        Ok(if self.points.is_empty() {
            *pose
        } else {
            track_pose(field, &self.points, pose)
        })
    }

    /// Every return of the body scan.
    fn all_hits(&mut self) {
        self.points.clear();
        let hits = self.body.points.iter().filter(|p| p.hit);
        self.points.extend(hits.map(|p| [p.x_m, p.y_m]));
    }

    /// Up to `max_beams` returns of the body scan, evenly spaced.
    fn select(&mut self, max_beams: usize) {
        let hits = || self.body.points.iter().filter(|p| p.hit);
        let step = hits().count().div_ceil(max_beams).max(1);
        self.points.clear();
        self.points
            .extend(hits().step_by(step).map(|p| [p.x_m, p.y_m]));
    }
}

/// Outputs gathered along the run.
#[derive(Default)]
struct Outputs {
    trajectory: Vec<StampedPose2>,
    updates: Vec<UpdateRecord>,
    scans_outside_odometry: usize,
    scans_without_returns: usize,
    scans_stale: usize,
    returns: usize,
    returns_off_wall: usize,
}

impl Outputs {
    fn count_off_wall(
        &mut self,
        field: &LikelihoodField,
        reach_m: f64,
        pose: &Pose2,
        body: &PlanarScan,
    ) -> f64 {
        let (mut returns, mut off_wall) = (0usize, 0usize);
        for p in body.points.iter().filter(|p| p.hit) {
            let (x, y) = pose.transform_point(p.x_m, p.y_m);
            returns += 1;
            if f64::from(field.distance_m(x, y)) > reach_m {
                off_wall += 1;
            }
        }
        self.returns += returns;
        self.returns_off_wall += off_wall;
        off_wall as f64 / returns.max(1) as f64
    }

    fn finish(self) -> LocalizeResult {
        LocalizeResult {
            trajectory: self.trajectory,
            updates: self.updates,
            scans_outside_odometry: self.scans_outside_odometry,
            scans_without_returns: self.scans_without_returns,
            scans_stale: self.scans_stale,
            off_wall_share: self.returns_off_wall as f64 / self.returns.max(1) as f64,
        }
    }
}

/// Particles drawn about a given start pose (at least; `min_particles` when larger): the
/// start may be off by the initial sigmas, wider than the cloud KLD sampling keeps later.
const INITIAL_TRACKING_PARTICLES: usize = 1000;

/// The filter between scans.
struct State<'a> {
    options: &'a LocalizeOptions,
    motion: OdometryModelOptions,
    particles: ParticleSet,
    streams: Streams,
    bins: KldBins,
    /// The odometry at the last update (`None` before the first).
    odom_at_update: Option<Pose2>,
    estimate: Estimate,
    /// Tracking one place (see [`UpdateRecord::converged`]).
    converged: bool,
    /// Augmented MCL's slow and fast averages of the fit (`None` before the first update).
    averages: Option<(f64, f64)>,
    /// The last converged estimate that called for no random particles, and the odometry
    /// there: where local recovery searches.
    last_good: Option<(Pose2, Pose2)>,
}

impl<'a> State<'a> {
    fn new(
        options: &'a LocalizeOptions,
        free: &FreeSpace<'_>,
        initial_pose: Option<Pose2>,
        seed: u64,
    ) -> Self {
        let mut streams = Streams::new(seed);
        let particles = match initial_pose {
            Some(p) => ParticleSet::around(
                &p,
                (
                    options.initial_sigma[0],
                    options.initial_sigma[1].to_radians(),
                ),
                options
                    .max_particles
                    .min(options.min_particles.max(INITIAL_TRACKING_PARTICLES)),
                &mut streams.sequential,
            ),
            None => ParticleSet::over(free, options.max_particles, &mut streams.sequential),
        };
        let [alpha1, alpha2, alpha3, alpha4] = options.motion_alphas;
        State {
            options,
            motion: OdometryModelOptions {
                model: OdometryModel::Thrun,
                alpha1,
                alpha2,
                alpha3,
                alpha4,
                ..OdometryModelOptions::default()
            },
            particles,
            streams,
            bins: KldBins::new(options.kld_bin[0], options.kld_bin[1].to_radians()),
            odom_at_update: None,
            estimate: Estimate {
                pose: initial_pose.unwrap_or(Pose2::IDENTITY),
                mass: 0.0,
            },
            converged: false,
            averages: None,
            last_good: None,
        }
    }

    /// True at the first scan, and once the odometry moved or turned enough since the last
    /// update.
    fn wants_update(&self, odom: &Pose2) -> bool {
        let Some(last) = self.odom_at_update else {
            return true;
        };
        let d = last.between(odom);
        d.translation_norm_m() >= self.options.update_min[0]
            || wrap_angle(d.yaw_rad).abs() >= self.options.update_min[1].to_radians()
    }

    /// The pose at a scan with odometry `odom`: the last estimate moved by the odometry since.
    fn pose_at(&self, odom: &Pose2) -> Pose2 {
        match self.odom_at_update {
            Some(last) => self.estimate.pose.compose(&last.between(odom)),
            None => self.estimate.pose,
        }
    }

    /// Predict, weigh, estimate, resample.
    fn update(
        &mut self,
        field: &LikelihoodField,
        free: &FreeSpace<'_>,
        points: &[[f64; 2]],
        stamp_ns: i64,
        odom: &Pose2,
    ) -> UpdateRecord {
        if let Some(last) = self.odom_at_update {
            self.particles
                .predict(&self.motion, (&last, odom), &mut self.streams);
        }
        self.odom_at_update = Some(*odom);
        let sharpness = if self.converged {
            Sharpness::Tracking
        } else {
            Sharpness::Global
        };
        let weighed = self.particles.poses.len();
        // Random particles just injected are tempered too: one that happens to fit this scan
        // better than a cluster the scan disturbed must not take the estimate at once.
        let searching = !self.converged || self.particles.injected.iter().any(|&i| i);
        let neff_floor = searching.then_some(self.options.likelihood.global_neff_share);
        let log_mean = self.particles.weigh(field, sharpness, points, neff_floor);
        let fit = (log_mean / points.len() as f64).exp();
        let o = self.options;
        self.estimate = estimate(
            &self.particles.poses,
            &self.particles.weights,
            &ClusterShape {
                radius_m: o.cluster_radius[0],
                yaw_rad: o.cluster_radius[1].to_radians(),
            },
        );
        let core_fit = core_fit(
            field,
            sharpness,
            points,
            &self.estimate.pose,
            o.recovery.core_share,
        );
        let inject_probability = self.track_fit(core_fit);
        self.converged = self.estimate.mass >= o.converged_mass;
        if inject_probability == 0.0 && self.converged {
            self.last_good = Some((self.estimate.pose, *odom));
        }
        let near = match self.last_good {
            // The odometry since may be the glitch that lost the robot: widen by its travel.
            Some((pose, odom_then)) => {
                let travel_m = odom_then.between(odom).translation_norm_m();
                (pose, o.recovery.local_sigma_m + travel_m)
            }
            None => (self.estimate.pose, o.recovery.local_sigma_m),
        };
        let injected = self.particles.resample(
            &ResamplePlan {
                inject_probability,
                min_particles: o.min_particles,
                max_particles: o.max_particles,
                kld_error: o.kld_error,
                kld_z: o.kld_z,
                near,
            },
            &mut self.bins,
            free,
            &mut self.streams.sequential,
        );
        UpdateRecord {
            stamp_ns,
            particles: weighed,
            injected,
            mass: self.estimate.mass,
            fit,
            core_fit,
            converged: self.converged,
            off_wall_share: 0.0,
        }
    }

    /// Moves the estimate to the best match of `points` (every return) in the field, and
    /// every particle with it: the cloud's mean lags behind poor odometry by the cloud's
    /// spread, a match of the whole scan does not.
    fn refine(&mut self, field: &LikelihoodField, points: &[[f64; 2]]) {
        let refined = refine_pose(field, points, &self.estimate.pose);
        let moved = refined.compose(&self.estimate.pose.inverse());
        for p in &mut self.particles.poses {
            *p = moved.compose(p);
        }
        self.estimate.pose = refined;
    }

    /// Updates augmented MCL's averages with `fit`; returns the probability of a random
    /// particle, `1 - fast / (ratio * slow)` when the recent fit fell below that share of the
    /// long-run one.
    fn track_fit(&mut self, fit: f64) -> f64 {
        let [a_slow, a_fast] = self.options.recovery.alphas;
        let (slow, fast) = match self.averages {
            None => (fit, fit),
            Some((s, f)) => (s + a_slow * (fit - s), f + a_fast * (fit - f)),
        };
        self.averages = Some((slow, fast));
        let ratio = self.options.recovery.fit_ratio;
        if slow > 0.0 {
            (1.0 - fast / (ratio * slow)).max(0.0)
        } else {
            0.0
        }
    }
}

/// The geometric mean likelihood of the best-fitting `share` of `points_body` (at least one
/// return) at `pose`: a fit that parts of the scan the map does not hold cannot drag down.
pub(super) fn core_fit(
    field: &LikelihoodField,
    sharpness: Sharpness,
    points_body: &[[f64; 2]],
    pose: &Pose2,
    share: f64,
) -> f64 {
    let mut each: Vec<f64> = points_body
        .iter()
        .map(|p| {
            let (x, y) = pose.transform_point(p[0], p[1]);
            f64::from(field.log_likelihood(sharpness, x, y))
        })
        .collect();
    if each.is_empty() {
        return 0.0;
    }
    each.sort_by(|a, b| b.total_cmp(a));
    let kept = ((each.len() as f64 * share).ceil() as usize).clamp(1, each.len());
    (each[..kept].iter().sum::<f64>() / kept as f64).exp()
}
