//! The humanoid (THOR-like): walks the world's route with a gait sway, turns and pitches its
//! head (so some beams hit the floor), and records drifting odometry poses, IMU attitude,
//! joint angles and a Hokuyo UTM-30LX on the head, in the layout of
//! `pfslam_io::humanoid`.
//!
//! Ground truth (written by [`crate::dataset::write_humanoid_sim`]): `ground_truth.tum` (true
//! pose at every LiDAR stamp) and `beam_labels.csv`
//! (header `timestamp_ns,labels`; per scan one string of N digits, one per beam:
//! `0` no return, `1` obstacle, `2` floor) — the floor hits are what a z filter must remove.

use super::path::{DriveProfile, Motion};
use super::raycast::{BeamErrors, RayCaster, ScanBeams, beam_directions, cast_scan};
use super::truth::TrueMap;
use super::world::World;
use super::{SimError, SimOptions, jumped_stream_vec, jumped_streams, normal, sample_times};
use pfslam::geometry::{Pose2, Rigid3, StampedPose2};
use pfslam::sensors::humanoid::{
    HumanoidCalibration, HumanoidDataset, ImuSample, JointSample, humanoid_recording,
};
use pfslam::sensors::{Recording, ScanSet};
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use std::f64::consts::PI;

pub use super::raycast::{BEAM_FLOOR, BEAM_NONE, BEAM_OBSTACLE};

const SCAN_BLOCK: usize = 64;

/// A simulated humanoid recording with its ground truth.
#[derive(Debug, Clone)]
pub struct HumanoidSimOutput {
    /// The dataset.
    pub dataset: HumanoidDataset,
    /// True pose at every LiDAR stamp.
    pub ground_truth: Vec<StampedPose2>,
    /// Per scan, per beam: [`BEAM_NONE`], [`BEAM_OBSTACLE`] or [`BEAM_FLOOR`] (flat, like
    /// the ranges).
    pub beam_labels: Vec<u8>,
    /// The true map.
    pub true_map: TrueMap,
    /// The options used.
    pub options: SimOptions,
    /// The world in world-file form.
    pub world_text: String,
    /// Distance walked (m).
    pub distance_m: f64,
}

impl HumanoidSimOutput {
    /// Number of beams that hit the floor.
    pub fn ground_beam_count(&self) -> usize {
        self.beam_labels
            .iter()
            .filter(|&&l| l == BEAM_FLOOR)
            .count()
    }

    /// The common recording (see [`humanoid_recording`]) with the ground truth attached.
    pub fn recording(&self) -> Recording {
        let mut r = humanoid_recording(&self.dataset, "humanoid-sim");
        r.ground_truth = Some(self.ground_truth.clone());
        r
    }
}

/// Neck yaw and head pitch (rad) at time `t_s`.
fn joints_at(head: &super::HumanoidSimHead, t_s: f64) -> (f64, f64) {
    let yaw = head.neck_yaw_amplitude_rad * (2.0 * PI * t_s / head.neck_yaw_period_s).sin();
    let f = 0.5 - 0.5 * (2.0 * PI * t_s / head.pitch_period_s).cos();
    (
        yaw,
        head.pitch_min_rad + f * (head.pitch_max_rad - head.pitch_min_rad),
    )
}

/// Body roll and pitch from the gait (rad) at time `t_s`.
fn sway_at(h: &super::HumanoidSimOptions, t_s: f64) -> (f64, f64) {
    let w = 2.0 * PI * h.step_frequency_hz * t_s;
    (
        h.sway_amplitude_rad * w.sin(),
        0.5 * h.sway_amplitude_rad * (2.0 * w + 0.7).sin(),
    )
}

/// Simulates the humanoid on `world` with `opts` (seed included).
pub fn simulate_humanoid(world: &World, opts: &SimOptions) -> Result<HumanoidSimOutput, SimError> {
    opts.validate()?;
    let h = &opts.humanoid;
    let cal = HumanoidCalibration::default();
    let motion = Motion::plan(
        world,
        opts.duration_s,
        &DriveProfile {
            cruise_mps: h.walk_speed_mps,
            accel_mps2: h.max_accel_mps2,
            decel_mps2: h.max_accel_mps2,
            lateral_mps2: h.max_lateral_accel_mps2,
            corner_radius_m: h.corner_radius_m,
            standstill_s: 1.0,
        },
    )?;
    let [mut rng_stamps, mut rng_odo, mut rng_imu, lidar_base] =
        jumped_streams(Xoshiro256PlusPlus::seed_from_u64(opts.seed));
    let jitter = h.errors.stamp_jitter_std_ns;
    let odo_times = sample_times(opts, h.odometry_rate_hz, 0.0, jitter, &mut rng_stamps);
    let imu_times = sample_times(opts, h.odometry_rate_hz, 0.002, jitter, &mut rng_stamps);
    let joint_times = sample_times(opts, h.odometry_rate_hz, 0.004, jitter, &mut rng_stamps);
    let lidar_times = sample_times(opts, h.lidar_rate_hz, 0.011, jitter, &mut rng_stamps);

    let odometry = simulate_odometry(&motion, h, &odo_times, &mut rng_odo);
    let imu = simulate_imu(&motion, h, &imu_times, &mut rng_imu);
    let joints = simulate_joints(h, &joint_times, &mut rng_imu);
    let nb = cal.lidar.beam_count;
    let (ranges, labels) = cast_scans(world, &motion, (h, &cal), &lidar_times, lidar_base);
    let mut lidar = ScanSet::new(nb);
    lidar.stamps_ns = lidar_times.iter().map(|x| x.1).collect();
    lidar.ranges_m = ranges;
    let ground_truth = lidar_times
        .iter()
        .map(|&(t, stamp_ns)| StampedPose2 {
            stamp_ns,
            pose: motion.pose_at(t).0,
        })
        .collect();
    let true_map = TrueMap::rasterize(
        world,
        opts.truth_map_resolution_m,
        [h.truth_band_min_m, h.truth_band_max_m],
        5.0,
    );
    Ok(HumanoidSimOutput {
        dataset: HumanoidDataset {
            calibration: cal,
            odometry,
            imu,
            joints,
            lidar,
        },
        ground_truth,
        beam_labels: labels,
        true_map,
        options: opts.clone(),
        world_text: world.to_text(),
        distance_m: motion.s_at(opts.duration_s),
    })
}

/// The odometry at `times`: true increments with scale error, heading drift and noise,
/// integrated.
fn simulate_odometry(
    motion: &Motion,
    h: &super::HumanoidSimOptions,
    times: &[(f64, i64)],
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<StampedPose2> {
    let mut odometry = Vec::with_capacity(times.len());
    let dt = 1.0 / h.odometry_rate_hz;
    let mut prev_true = motion.pose_at(times.first().map_or(0.0, |o| o.0)).0;
    let mut odo = prev_true;
    for &(t, stamp_ns) in times {
        let p = motion.pose_at(t).0;
        let d = prev_true.between(&p);
        prev_true = p;
        let (nx, ny, nth) = if h.errors.odometry_noise_std > 0.0 {
            let sd = h.errors.odometry_noise_std;
            (sd * normal(rng), sd * normal(rng), sd * normal(rng))
        } else {
            (0.0, 0.0, 0.0)
        };
        let k = 1.0 + h.errors.odometry_scale_error;
        let noisy = Pose2::new(
            d.x_m * k + nx,
            d.y_m * k + ny,
            d.yaw_rad + h.errors.odometry_yaw_drift_rad_per_s * dt + nth,
        );
        odo = odo.compose(&noisy);
        odometry.push(StampedPose2 {
            stamp_ns,
            pose: odo,
        });
    }
    odometry
}

/// The IMU at `times`: the body's sway and its true yaw with drift and noise.
fn simulate_imu(
    motion: &Motion,
    h: &super::HumanoidSimOptions,
    times: &[(f64, i64)],
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<ImuSample> {
    let t0 = times.first().map_or(0.0, |o| o.0);
    times
        .iter()
        .map(|&(t, stamp_ns)| {
            let (roll, pitch) = sway_at(h, t);
            let yaw = motion.pose_at(t).1 + h.errors.imu_yaw_drift_rad_per_s * (t - t0);
            let sd = h.errors.imu_noise_std_rad;
            let mut n = || if sd > 0.0 { sd * normal(rng) } else { 0.0 };
            ImuSample {
                stamp_ns,
                roll_rad: roll + n(),
                pitch_rad: pitch + n(),
                yaw_rad: pfslam::geometry::wrap_angle(yaw + n()),
            }
        })
        .collect()
}

/// The head's joint angles at `times`, with noise (drawn from the IMU's stream, after it).
fn simulate_joints(
    h: &super::HumanoidSimOptions,
    times: &[(f64, i64)],
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<JointSample> {
    times
        .iter()
        .map(|&(t, stamp_ns)| {
            let (yaw, pitch) = joints_at(&h.head, t);
            let sd = h.errors.joint_noise_std_rad;
            let mut n = || if sd > 0.0 { sd * normal(rng) } else { 0.0 };
            JointSample {
                stamp_ns,
                neck_yaw_rad: yaw + n(),
                head_pitch_rad: pitch + n(),
            }
        })
        .collect()
}

/// Every scan at `times` with its beams' labels, cast from the head's true pose (body
/// pose, sway, neck and head joints): blocks of [`SCAN_BLOCK`] scans in parallel, each with
/// its own stream jumped from `base`.
fn cast_scans(
    world: &World,
    motion: &Motion,
    (h, cal): (&super::HumanoidSimOptions, &HumanoidCalibration),
    times: &[(f64, i64)],
    base: Xoshiro256PlusPlus,
) -> (Vec<f32>, Vec<u8>) {
    let geom = cal.lidar;
    let nb = geom.beam_count;
    let max_range = f64::from(geom.range_max_m);
    let caster = RayCaster::new(world, 1.0, 40.0);
    let mut ranges = vec![0.0f32; times.len() * nb];
    let mut labels = vec![BEAM_NONE; times.len() * nb];
    let n_blocks = times.len().div_ceil(SCAN_BLOCK);
    let block_rngs = jumped_stream_vec(base, n_blocks);
    let beams = beam_directions(&geom);
    let errors = BeamErrors {
        range_noise_std_m: h.errors.lidar_range_noise_std_m,
        dropout_prob: h.errors.lidar_dropout_prob,
        max_range_prob: 0.0,
    };
    ranges
        .par_chunks_mut(SCAN_BLOCK * nb)
        .zip(labels.par_chunks_mut(SCAN_BLOCK * nb))
        .zip(block_rngs.into_par_iter())
        .enumerate()
        .for_each(|(bi, ((rchunk, lchunk), mut rng))| {
            for (k, (scan, lab)) in rchunk.chunks_mut(nb).zip(lchunk.chunks_mut(nb)).enumerate() {
                let t = times[bi * SCAN_BLOCK + k].0;
                let pose = motion.pose_at(t).0;
                let (roll, pitch) = sway_at(h, t);
                let (ny, np) = joints_at(&h.head, t);
                let world_from_body =
                    Rigid3::from_rpy(roll, pitch, pose.yaw_rad, [pose.x_m, pose.y_m, 0.0]);
                let wl = world_from_body.compose(&cal.body_from_lidar(ny, np));
                let sensor = ScanBeams {
                    world_from_sensor: &wl,
                    beams: &beams,
                    max_range_m: max_range,
                };
                cast_scan(&caster, &sensor, &errors, &mut rng, scan, Some(lab));
            }
        });
    (ranges, labels)
}
