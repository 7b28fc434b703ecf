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

use super::path::Path as DrivePath;
use super::raycast::RayCaster;
use super::truth::TrueMap;
use super::world::World;
use super::{SimError, SimOptions, sim_toml};
use crate::geometry::{Pose2, StampedPose2};
use crate::sensors::{CarCalibration, CarDataset, EncoderSample, FogSample, ScanSet};
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use std::path::Path;

/// Time step of the motion integration (s).
const DRIVE_DT_S: f64 = 1e-3;
/// Scans per parallel block (each block has its own jumped random stream).
const SCAN_BLOCK: usize = 256;

/// A simulated car recording with its ground truth.
#[derive(Debug, Clone)]
pub struct CarSimOutput {
    /// The dataset, as the real car's files would give it.
    pub dataset: CarDataset,
    /// True pose at every recorded LiDAR stamp.
    pub ground_truth: Vec<StampedPose2>,
    /// The true map (rule in [`super::truth`]).
    pub true_map: TrueMap,
    /// The options used (with the seed).
    pub options: SimOptions,
    /// The world, in world-file form (written as `world.world`).
    pub world_text: String,
    /// Distance driven (m).
    pub distance_m: f64,
}

/// The true motion: arc length sampled every [`DRIVE_DT_S`].
struct Motion {
    path: DrivePath,
    s: Vec<f64>,
    standstill_s: f64,
}

impl Motion {
    fn s_at(&self, t_s: f64) -> f64 {
        let t = (t_s - self.standstill_s).max(0.0) / DRIVE_DT_S;
        let k = (t.floor() as usize).min(self.s.len() - 2);
        let f = (t - k as f64).min(1.0);
        self.s[k] + f * (self.s[k + 1] - self.s[k])
    }

    fn pose_at(&self, t_s: f64) -> (Pose2, f64) {
        let p = self.path.at(self.s_at(t_s));
        (Pose2::new(p.x_m, p.y_m, p.yaw_rad), p.yaw_rad)
    }
}

fn normal(rng: &mut Xoshiro256PlusPlus) -> f64 {
    rng.sample(StandardNormal)
}

/// Nominal sample times `phase + k / rate` over the duration, with recorded stamps (ns) =
/// start + time + clipped jitter.
fn sample_times(
    opts: &SimOptions,
    rate_hz: f64,
    phase_s: f64,
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<(f64, i64)> {
    let n = ((opts.duration_s - phase_s) * rate_hz).floor().max(0.0) as usize + 1;
    let period_ns = 1e9 / rate_hz;
    let clip = 0.4 * period_ns;
    (0..n)
        .map(|k| {
            let t = phase_s + k as f64 / rate_hz;
            let jitter = if opts.car.stamp_jitter_std_ns > 0.0 {
                (normal(rng) * opts.car.stamp_jitter_std_ns).clamp(-clip, clip)
            } else {
                0.0
            };
            (t, opts.start_stamp_ns + (t * 1e9 + jitter).round() as i64)
        })
        .collect()
}

/// Simulates the car on `world` with `opts` (seed included).
pub fn simulate_car(world: &World, opts: &SimOptions) -> Result<CarSimOutput, SimError> {
    opts.validate()?;
    if world.route.len() < 2 {
        return Err(SimError::BadRoute(format!(
            "world {:?} has no route",
            world.name
        )));
    }
    let c = &opts.car;
    let calib = CarCalibration::ucsd();
    let path = DrivePath::from_route(&world.route, c.corner_radius_m)?;
    let steps = ((opts.duration_s + 1.0) / DRIVE_DT_S).ceil() as usize + 2;
    let s = path.drive(
        c.cruise_speed_mps,
        c.max_accel_mps2,
        c.max_decel_mps2,
        c.max_lateral_accel_mps2,
        DRIVE_DT_S,
        steps,
    );
    let motion = Motion {
        path,
        s,
        standstill_s: c.initial_standstill_s,
    };

    // Independent streams: stamps, encoder, fog, row drops, lidar blocks.
    let mut base = Xoshiro256PlusPlus::seed_from_u64(opts.seed);
    let mut stream = || {
        let r = base.clone();
        base.jump();
        r
    };
    let mut rng_stamps = stream();
    let mut rng_enc = stream();
    let mut rng_fog = stream();
    let mut rng_drop = stream();
    let lidar_base = stream();

    let enc_times = sample_times(opts, c.encoder_rate_hz, 0.0, &mut rng_stamps);
    let fog_times = sample_times(opts, c.fog_rate_hz, 0.000_37, &mut rng_stamps);
    let lidar_times = sample_times(opts, c.lidar_rate_hz, 0.003_1, &mut rng_stamps);

    // Encoders: cumulative TRUE wheel rotation (m of tyre circumference), with slip.
    let e = &calib.encoder;
    let half_base = 0.5 * e.wheel_base_m;
    let true_d_left = e.left_wheel_diameter_m * (1.0 + c.left_wheel_diameter_error);
    let true_d_right = e.right_wheel_diameter_m * (1.0 + c.right_wheel_diameter_error);
    let ticks = f64::from(e.resolution_ticks);
    let mut encoder = Vec::with_capacity(enc_times.len());
    let (mut rot_l, mut rot_r) = (0.0f64, 0.0f64);
    let (mut prev_l, mut prev_r) = (0.0f64, 0.0f64);
    for &(t, stamp_ns) in &enc_times {
        let sv = motion.s_at(t);
        let dl = motion.path.offset_distance_m(sv, half_base);
        let dr = motion.path.offset_distance_m(sv, -half_base);
        let (slip_l, slip_r) = if c.wheel_slip_std > 0.0 {
            (
                1.0 + c.wheel_slip_std * normal(&mut rng_enc),
                1.0 + c.wheel_slip_std * normal(&mut rng_enc),
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

    // FOG: true yaw increments between consecutive true sampling times.
    let mut fog = Vec::with_capacity(fog_times.len());
    let fog_dt = 1.0 / c.fog_rate_hz;
    let noise_row = c.fog_noise_rad_per_sqrt_s * fog_dt.sqrt();
    let mut prev_yaw = motion
        .pose_at(fog_times.first().map_or(0.0, |f| f.0) - fog_dt)
        .1;
    for &(t, stamp_ns) in &fog_times {
        let yaw = motion.pose_at(t).1;
        let (nr, np, ny) = if noise_row > 0.0 {
            (
                noise_row * normal(&mut rng_fog),
                noise_row * normal(&mut rng_fog),
                noise_row * normal(&mut rng_fog),
            )
        } else {
            (0.0, 0.0, 0.0)
        };
        fog.push(FogSample {
            stamp_ns,
            delta_roll_rad: nr,
            delta_pitch_rad: np,
            delta_yaw_rad: yaw - prev_yaw + c.fog_yaw_bias_rad_per_s * fog_dt + ny,
        });
        prev_yaw = yaw;
    }

    // LiDAR: beam directions in the body frame, cast from each scan's true pose.
    let geom = calib.lidar;
    let bl = &calib.body_from_lidar;
    let dirs_body: Vec<[f64; 3]> = (0..geom.beam_count)
        .map(|i| {
            let a = geom.beam_angle_rad(i);
            let v = bl.rotation * nalgebra::Vector3::new(a.cos(), a.sin(), 0.0);
            let v = v / v.norm();
            [v[0], v[1], v[2]]
        })
        .collect();
    let origin_body = [bl.translation[0], bl.translation[1], bl.translation[2]];
    let caster = RayCaster::new(world, 4.0, 100.0);
    let nb = geom.beam_count;
    let max_range = f64::from(geom.range_max_m);
    let mut ranges = vec![0.0f32; lidar_times.len() * nb];
    let n_blocks = lidar_times.len().div_ceil(SCAN_BLOCK);
    let mut block_rngs = Vec::with_capacity(n_blocks);
    let mut r = lidar_base;
    for _ in 0..n_blocks {
        block_rngs.push(r.clone());
        r.jump();
    }
    ranges
        .par_chunks_mut(SCAN_BLOCK * nb)
        .zip(block_rngs.into_par_iter())
        .enumerate()
        .for_each(|(bi, (chunk, mut rng))| {
            for (k, scan) in chunk.chunks_mut(nb).enumerate() {
                let t = lidar_times[bi * SCAN_BLOCK + k].0;
                let (pose, _) = motion.pose_at(t);
                cast_scan(
                    &caster,
                    &pose,
                    origin_body,
                    &dirs_body,
                    max_range,
                    c,
                    &mut rng,
                    scan,
                );
            }
        });
    let mut ground_truth = Vec::with_capacity(lidar_times.len());
    let mut lidar = ScanSet::new(nb);
    lidar.stamps_ns.reserve(lidar_times.len());
    lidar.ranges_m.reserve(ranges.len());
    let dropped = |rng: &mut Xoshiro256PlusPlus| {
        c.drop_row_prob > 0.0 && rng.random::<f64>() < c.drop_row_prob
    };
    for (i, &(t, stamp_ns)) in lidar_times.iter().enumerate() {
        if dropped(&mut rng_drop) {
            continue;
        }
        lidar.push(stamp_ns, &ranges[i * nb..(i + 1) * nb]);
        ground_truth.push(StampedPose2 {
            stamp_ns,
            pose: motion.pose_at(t).0,
        });
    }
    // The first rows are never dropped: they anchor the streams.
    let mut k = 0usize;
    encoder.retain(|_| {
        k += 1;
        k == 1 || !dropped(&mut rng_drop)
    });
    let mut k = 0usize;
    fog.retain(|_| {
        k += 1;
        k == 1 || !dropped(&mut rng_drop)
    });

    let end_t = opts.duration_s;
    let distance_m = motion.s_at(end_t);
    let true_map = TrueMap::rasterize(
        world,
        opts.truth_map_resolution_m,
        [opts.truth_band_min_m, opts.truth_band_max_m],
        20.0,
    );
    Ok(CarSimOutput {
        dataset: CarDataset {
            calibration: calib,
            encoder,
            fog,
            lidar,
            stereo_stamps_ns: Vec::new(),
        },
        ground_truth,
        true_map,
        options: opts.clone(),
        world_text: world.to_text(),
        distance_m,
    })
}

/// Casts one scan into `out` (m, 0.0 = no return) with the configured errors.
#[allow(clippy::too_many_arguments)]
fn cast_scan(
    caster: &RayCaster,
    pose: &Pose2,
    origin_body: [f64; 3],
    dirs_body: &[[f64; 3]],
    max_range_m: f64,
    c: &super::CarSimOptions,
    rng: &mut Xoshiro256PlusPlus,
    out: &mut [f32],
) {
    let (sy, cy) = pose.yaw_rad.sin_cos();
    let o = [
        pose.x_m + cy * origin_body[0] - sy * origin_body[1],
        pose.y_m + sy * origin_body[0] + cy * origin_body[1],
        origin_body[2],
    ];
    for (d_b, r) in dirs_body.iter().zip(out.iter_mut()) {
        let d = [cy * d_b[0] - sy * d_b[1], sy * d_b[0] + cy * d_b[1], d_b[2]];
        let mut range = match caster.cast(o, d, max_range_m) {
            Some(h) => h.range_m,
            None => 0.0,
        };
        if range > 0.0 {
            if c.lidar_range_noise_std_m > 0.0 {
                range = (range + c.lidar_range_noise_std_m * normal(rng))
                    .clamp(0.001, max_range_m - 1e-3);
            }
            if c.lidar_dropout_prob > 0.0 && rng.random::<f64>() < c.lidar_dropout_prob {
                range = 0.0;
            }
        }
        if c.lidar_max_range_prob > 0.0 && rng.random::<f64>() < c.lidar_max_range_prob {
            range = max_range_m;
        }
        *r = range as f32;
    }
}

/// Writes a simulated car recording into `dir`: the dataset in the car's layout, plus
/// `ground_truth.tum`, `true_map.{png,pgm,yaml}`, `world.world` and `sim.toml`.
pub fn write_car_sim(dir: &Path, out: &CarSimOutput) -> Result<(), SimError> {
    std::fs::create_dir_all(dir).map_err(|e| crate::io::IoError::io(dir, e))?;
    crate::io::tum::write_tum(&dir.join("ground_truth.tum"), &out.ground_truth)?;
    out.true_map.write(dir, "true_map")?;
    crate::io::write_bytes_atomic(&dir.join("world.world"), out.world_text.as_bytes())?;
    crate::io::write_bytes_atomic(&dir.join("sim.toml"), sim_toml(&out.options)?.as_bytes())?;
    Ok(())
}
