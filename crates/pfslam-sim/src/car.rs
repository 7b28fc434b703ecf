//! The seed car: drives the world's route and records encoders, FOG and LiDAR exactly as the
//! real car's `encoder.csv`, `fog.csv` and `lidar.csv` do, with the real calibration.
//!
//! Model: the body origin is the middle of the rear axle (pure rolling, no side slip); the
//! heading is the path tangent. The wheels sit at `+-wheel_base / 2`, so the left wheel
//! travels `integral (1 - kappa b / 2) ds`. Encoder counts are `floor(rotation * 4096)` of the
//! TRUE wheel (diameter `calibrated * (1 + error)`, slip applied per interval); FOG rows are
//! yaw increments between consecutive TRUE sampling times plus bias and white noise (roll and
//! pitch increments are noise only: the world is flat). Each LiDAR scan is cast at the pose of
//! its true sampling time (the 10 ms sweep is treated as instantaneous). Recorded stamps are
//! the true times plus jitter; the ground truth pairs each recorded LiDAR stamp with the true
//! pose of that scan.

use super::path::{DriveProfile, Motion};
use super::raycast::{BeamErrors, RayCaster, ScanBeams, beam_directions, cast_scan};
use super::scan_truth::ScanSurfaceTruth;
use super::truth::TrueMap;
use super::world::World;
use super::{SimError, SimOptions, jumped_stream_vec, jumped_streams, normal, sample_times};
use pfslam::geometry::{Rigid3, StampedPose2};
use pfslam::sensors::{CarCalibration, CarDataset, EncoderSample, FogSample, ScanSet};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;

/// Scans per parallel block (each block has its own jumped random stream).
const SCAN_BLOCK: usize = 256;

/// A simulated car recording with its ground truth.
#[derive(Debug, Clone)]
pub struct CarSimOutput {
    /// The dataset, as the real car's files would give it.
    pub dataset: CarDataset,
    /// True pose at every recorded LiDAR stamp.
    pub ground_truth: Vec<StampedPose2>,
    /// The fixed-band true map (rule in [`super::truth`]), written as `true_map_band.*`.
    pub true_map: TrueMap,
    /// The scan-surface truth (rule in [`super::scan_truth`]), written as `true_map.*` and
    /// `true_map_visible.*`: what the tilted LiDAR can observe along the true path.
    pub scan_truth: ScanSurfaceTruth,
    /// The options used (with the seed).
    pub options: SimOptions,
    /// The world, in world-file form (written as `world.world`).
    pub world_text: String,
    /// Distance driven (m).
    pub distance_m: f64,
    /// True pose of each stereo pair, keyed by its recorded stamp (empty when
    /// `car.stereo_rate_hz` is 0). The pairs are rendered by [`crate::dataset::write_car_sim`],
    /// not kept in memory (a pair is 1.4 MB).
    pub stereo_poses: Vec<StampedPose2>,
    /// The world, for rendering the stereo pairs.
    pub world: World,
}

impl CarSimOutput {
    /// The car's common [`pfslam::sensors::Recording`] (odometry = dead reckoning of the
    /// simulated encoders and FOG, scans, mount; see [`pfslam::motion::car_recording`]) with
    /// the ground truth attached.
    pub fn recording(
        &self,
        motion: &pfslam::motion::MotionOptions,
    ) -> Result<pfslam::sensors::Recording, pfslam::motion::MotionError> {
        let mut r = pfslam::motion::car_recording(&self.dataset, motion, "car-sim")?;
        r.ground_truth = Some(self.ground_truth.clone());
        Ok(r)
    }
}

/// Simulates the car on `world` with `opts` (seed included).
pub fn simulate_car(world: &World, opts: &SimOptions) -> Result<CarSimOutput, SimError> {
    opts.validate()?;
    let c = &opts.car;
    let calib = CarCalibration::ucsd();
    let motion = plan_drive(world, opts)?;

    // Independent streams: stamps, encoder, fog, row drops, lidar blocks.
    let [
        mut rng_stamps,
        mut rng_enc,
        mut rng_fog,
        mut rng_drop,
        lidar_base,
    ] = jumped_streams(Xoshiro256PlusPlus::seed_from_u64(opts.seed));
    let times = SensorTimes::sample(opts, &mut rng_stamps);

    let mut encoder = simulate_encoder(&motion, c, &calib, &times.encoder, &mut rng_enc);
    let mut fog = simulate_fog(&motion, c, &times.fog, &mut rng_fog);
    let ranges = cast_scans(world, &motion, &calib, (c, &times.lidar), lidar_base);
    let drop_prob = c.errors.drop_row_prob;
    // The row drops draw from one stream: the LiDAR rows, then the encoder's, then the FOG's.
    let (lidar, ground_truth) = keep_scans(
        &motion,
        &times.lidar,
        (&ranges, calib.lidar.beam_count),
        drop_prob,
        &mut rng_drop,
    );
    drop_rows_after_first(&mut encoder, drop_prob, &mut rng_drop);
    drop_rows_after_first(&mut fog, drop_prob, &mut rng_drop);

    let stereo_poses: Vec<StampedPose2> = times
        .stereo
        .iter()
        .map(|&(t, stamp_ns)| StampedPose2 {
            stamp_ns,
            pose: motion.pose_at(t).0,
        })
        .collect();
    let end_t = opts.duration_s;
    let distance_m = motion.s_at(end_t);
    let true_map = TrueMap::rasterize(
        world,
        opts.truth_map_resolution_m,
        [opts.truth_band_min_m, opts.truth_band_max_m],
        20.0,
    );
    let scan_truth = ScanSurfaceTruth::for_car(world, &ground_truth, &calib, opts)?;
    Ok(CarSimOutput {
        dataset: CarDataset {
            calibration: calib,
            encoder,
            fog,
            lidar,
            stereo_stamps_ns: stereo_poses.iter().map(|p| p.stamp_ns).collect(),
        },
        ground_truth,
        true_map,
        scan_truth,
        options: opts.clone(),
        world_text: world.to_text(),
        distance_m,
        stereo_poses,
        world: world.clone(),
    })
}

/// The car's drive along the world's route with the speed limits of `[sim.car]`.
fn plan_drive(world: &World, opts: &SimOptions) -> Result<Motion, SimError> {
    let c = &opts.car;
    Motion::plan(
        world,
        opts.duration_s,
        &DriveProfile {
            cruise_mps: c.cruise_speed_mps,
            accel_mps2: c.max_accel_mps2,
            decel_mps2: c.max_decel_mps2,
            lateral_mps2: c.max_lateral_accel_mps2,
            corner_radius_m: c.corner_radius_m,
            standstill_s: c.initial_standstill_s,
        },
    )
}

/// The true sampling times and recorded stamps `(seconds, stamp_ns)` of each sensor.
struct SensorTimes {
    encoder: Vec<(f64, i64)>,
    fog: Vec<(f64, i64)>,
    lidar: Vec<(f64, i64)>,
    stereo: Vec<(f64, i64)>,
}

impl SensorTimes {
    /// Every sensor's times from the one stamp stream `rng`, each with its own phase.
    fn sample(opts: &SimOptions, rng: &mut Xoshiro256PlusPlus) -> Self {
        let c = &opts.car;
        let jitter = c.errors.stamp_jitter_std_ns;
        let encoder = sample_times(opts, c.encoder_rate_hz, 0.0, jitter, rng);
        let fog = sample_times(opts, c.fog_rate_hz, 0.000_37, jitter, rng);
        let lidar = sample_times(opts, c.lidar_rate_hz, 0.003_1, jitter, rng);
        // Drawn last, so switching stereo on leaves every other stream unchanged.
        let stereo = if c.stereo_rate_hz > 0.0 {
            sample_times(opts, c.stereo_rate_hz, 0.007_3, jitter, rng)
        } else {
            Vec::new()
        };
        SensorTimes {
            encoder,
            fog,
            lidar,
            stereo,
        }
    }
}

/// Whether `rng` drops a row, with probability `drop_prob` (no draw when it is 0).
fn dropped(drop_prob: f64, rng: &mut Xoshiro256PlusPlus) -> bool {
    drop_prob > 0.0 && rng.random::<f64>() < drop_prob
}

/// The scans recorded at `lidar_times` (`ranges`: `beams` per scan, in order) less the rows
/// dropped, and the true pose at each one kept.
fn keep_scans(
    motion: &Motion,
    lidar_times: &[(f64, i64)],
    (ranges, beams): (&[f32], usize),
    drop_prob: f64,
    rng: &mut Xoshiro256PlusPlus,
) -> (ScanSet, Vec<StampedPose2>) {
    let mut ground_truth = Vec::with_capacity(lidar_times.len());
    let mut lidar = ScanSet::new(beams);
    lidar.stamps_ns.reserve(lidar_times.len());
    lidar.ranges_m.reserve(ranges.len());
    for (i, &(t, stamp_ns)) in lidar_times.iter().enumerate() {
        if dropped(drop_prob, rng) {
            continue;
        }
        lidar.push(stamp_ns, &ranges[i * beams..(i + 1) * beams]);
        ground_truth.push(StampedPose2 {
            stamp_ns,
            pose: motion.pose_at(t).0,
        });
    }
    (lidar, ground_truth)
}

/// Drops rows with probability `drop_prob`, never the first: it anchors the stream.
fn drop_rows_after_first<T>(rows: &mut Vec<T>, drop_prob: f64, rng: &mut Xoshiro256PlusPlus) {
    let mut k = 0usize;
    rows.retain(|_| {
        k += 1;
        k == 1 || !dropped(drop_prob, rng)
    });
}

/// The wheel encoders at `times` (seconds, stamp): cumulative true wheel rotation (m of
/// tyre circumference) with slip, counted in ticks of the wheels' true (miscalibrated)
/// diameters.
fn simulate_encoder(
    motion: &Motion,
    c: &super::CarSimOptions,
    calib: &CarCalibration,
    times: &[(f64, i64)],
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<EncoderSample> {
    let e = &calib.encoder;
    let half_base = 0.5 * e.wheel_base_m;
    let true_d_left = e.left_wheel_diameter_m * (1.0 + c.errors.left_wheel_diameter_error);
    let true_d_right = e.right_wheel_diameter_m * (1.0 + c.errors.right_wheel_diameter_error);
    let ticks = f64::from(e.resolution_ticks);
    let mut encoder = Vec::with_capacity(times.len());
    let (mut rot_l, mut rot_r) = (0.0f64, 0.0f64);
    let (mut prev_l, mut prev_r) = (0.0f64, 0.0f64);
    for &(t, stamp_ns) in times {
        let sv = motion.s_at(t);
        let dl = motion.path.offset_distance_m(sv, half_base);
        let dr = motion.path.offset_distance_m(sv, -half_base);
        let (slip_l, slip_r) = if c.errors.wheel_slip_std > 0.0 {
            (
                1.0 + c.errors.wheel_slip_std * normal(rng),
                1.0 + c.errors.wheel_slip_std * normal(rng),
            )
        } else {
            (1.0, 1.0)
        };
        rot_l += (dl - prev_l) * slip_l;
        rot_r += (dr - prev_r) * slip_r;
        prev_l = dl;
        prev_r = dr;
        encoder.push(EncoderSample {
            stamp_ns,
            left_count: (rot_l / (std::f64::consts::PI * true_d_left) * ticks).floor() as i64,
            right_count: (rot_r / (std::f64::consts::PI * true_d_right) * ticks).floor() as i64,
        });
    }
    encoder
}

/// The FOG at `times`: true yaw increments between consecutive sampling times, with the
/// gyro's noise and yaw-rate bias.
fn simulate_fog(
    motion: &Motion,
    c: &super::CarSimOptions,
    times: &[(f64, i64)],
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<FogSample> {
    let mut fog = Vec::with_capacity(times.len());
    let fog_dt = 1.0 / c.fog_rate_hz;
    let noise_row = c.errors.fog_noise_rad_per_sqrt_s * fog_dt.sqrt();
    let mut prev_yaw = motion
        .pose_at(times.first().map_or(0.0, |f| f.0) - fog_dt)
        .1;
    for &(t, stamp_ns) in times {
        let yaw = motion.pose_at(t).1;
        let (nr, np, ny) = if noise_row > 0.0 {
            (
                noise_row * normal(rng),
                noise_row * normal(rng),
                noise_row * normal(rng),
            )
        } else {
            (0.0, 0.0, 0.0)
        };
        fog.push(FogSample {
            stamp_ns,
            delta_roll_rad: nr,
            delta_pitch_rad: np,
            delta_yaw_rad: yaw - prev_yaw + c.errors.fog_yaw_bias_rad_per_s * fog_dt + ny,
        });
        prev_yaw = yaw;
    }
    fog
}

/// Every scan at `times`, cast from its true pose with the real mount: blocks of
/// [`SCAN_BLOCK`] scans in parallel, each with its own stream jumped from `base`.
fn cast_scans(
    world: &World,
    motion: &Motion,
    calib: &CarCalibration,
    (c, times): (&super::CarSimOptions, &[(f64, i64)]),
    base: Xoshiro256PlusPlus,
) -> Vec<f32> {
    let geom = calib.lidar;
    let beams = beam_directions(&geom);
    let errors = BeamErrors {
        range_noise_std_m: c.errors.lidar_range_noise_std_m,
        dropout_prob: c.errors.lidar_dropout_prob,
        max_range_prob: c.errors.lidar_max_range_prob,
    };
    let caster = RayCaster::new(world, 4.0, 100.0);
    let nb = geom.beam_count;
    let max_range = f64::from(geom.range_max_m);
    let mut ranges = vec![0.0f32; times.len() * nb];
    let n_blocks = times.len().div_ceil(SCAN_BLOCK);
    let block_rngs = jumped_stream_vec(base, n_blocks);
    ranges
        .par_chunks_mut(SCAN_BLOCK * nb)
        .zip(block_rngs.into_par_iter())
        .enumerate()
        .for_each(|(bi, (chunk, mut rng))| {
            for (k, scan) in chunk.chunks_mut(nb).enumerate() {
                let t = times[bi * SCAN_BLOCK + k].0;
                let (pose, _) = motion.pose_at(t);
                let wl = Rigid3::from_pose2(&pose).compose(&calib.body_from_lidar);
                let sensor = ScanBeams {
                    world_from_sensor: &wl,
                    beams: &beams,
                    max_range_m: max_range,
                };
                cast_scan(&caster, &sensor, &errors, &mut rng, scan, None);
            }
        });
    ranges
}
