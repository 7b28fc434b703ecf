//! # pfslam-sim — simulated recordings with their ground truth
//!
//! The simulator, on top of the `pfslam` library: a digital twin of the seed car (and of the
//! humanoid's head LiDAR) driving through a [`World`], producing datasets in the real formats
//! plus their ground truth.
//!
//! - [`World`]: extruded polygons with heights on the ground plane, a ground texture and a
//!   route; built-in `campus` (car) and `office` (humanoid) worlds or a world file (format in
//!   [`world`]).
//! - [`RayCaster`]: 3-D ray casting against the world and the ground plane.
//! - [`simulate_car`]: the seed car with its real calibration
//!   ([`pfslam::sensors::CarCalibration::ucsd`]): encoders, FOG, the tilted LiDAR, and the
//!   configurable errors of [`CarSimErrors`], and optionally the stereo camera's raw pairs
//!   (`stereo_rate_hz`, rendered by [`camera::WorldScene`] through `pfslam-stereo`'s
//!   rendering); written as a dataset by [`dataset::write_car_sim`] (the humanoid by
//!   [`dataset::write_humanoid_sim`]) in `pfslam-io`'s formats.
//! - [`TrueMap`]: the world rasterised by the rule documented in [`truth`]; the car's
//!   scan-surface truth in [`scan_truth`].
//!
//! The options ([`SimOptions`], `[sim]` in the configuration) are declared in
//! `pfslam::config::sim` so the library's `Config` holds them, and re-exported here.
//!
//! Same options (including `seed`) -> identical output, whatever the number of threads.
#![deny(missing_docs)]

pub mod camera;
pub mod car;
pub mod dataset;
pub mod humanoid;
pub mod path;
pub mod raycast;
pub mod scan_truth;
pub mod truth;
pub mod world;

pub use camera::WorldScene;
pub use car::{CarSimOutput, simulate_car};
pub use humanoid::{HumanoidSimOutput, simulate_humanoid};
pub use raycast::{Hit, HitKind, RayCaster};
pub use scan_truth::ScanSurfaceTruth;
pub use truth::TrueMap;
pub use world::{Prism, World};

pub use pfslam::config::sim::{
    CarSimErrors, CarSimOptions, HumanoidSimErrors, HumanoidSimHead, HumanoidSimOptions,
    ScanTruthOptions, SimOptionError, SimOptions, TruthRays, Vehicle,
};

use serde::Serialize;

/// Errors of the simulator.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// Reading a world file or writing output failed.
    #[error(transparent)]
    Io(#[from] pfslam::files::IoError),
    /// No built-in world has this name.
    #[error("{0:?} is neither a built-in world (campus, office) nor an existing world file")]
    UnknownWorld(String),
    /// The route cannot be driven.
    #[error("bad route: {0}")]
    BadRoute(String),
    /// An option is out of range.
    #[error("bad simulator option: {0}")]
    BadOption(String),
    /// Rendering or encoding the stereo images failed.
    #[error(transparent)]
    Stereo(#[from] pfslam_stereo::StereoError),
}

impl From<SimOptionError> for SimError {
    fn from(e: SimOptionError) -> Self {
        SimError::BadOption(e.0)
    }
}

/// `N` independent random streams: `base`, then each the previous one jumped by 2^128 steps.
pub(crate) fn jumped_streams<const N: usize>(
    base: rand_xoshiro::Xoshiro256PlusPlus,
) -> [rand_xoshiro::Xoshiro256PlusPlus; N] {
    let v = jumped_stream_vec(base, N);
    std::array::from_fn(|i| v[i].clone())
}

/// `n` independent random streams (one per parallel block), as [`jumped_streams`].
pub(crate) fn jumped_stream_vec(
    base: rand_xoshiro::Xoshiro256PlusPlus,
    n: usize,
) -> Vec<rand_xoshiro::Xoshiro256PlusPlus> {
    let mut r = base;
    (0..n)
        .map(|_| {
            let out = r.clone();
            r.jump();
            out
        })
        .collect()
}

/// A standard normal sample.
pub(crate) fn normal(rng: &mut rand_xoshiro::Xoshiro256PlusPlus) -> f64 {
    use rand::RngExt;
    rng.sample(rand_distr::StandardNormal)
}

/// Nominal sample times `phase + k / rate` over the duration, each with its recorded stamp
/// (ns) = start + time + jitter (normal, clipped to +-40 % of the period so rows stay ordered).
pub(crate) fn sample_times(
    opts: &SimOptions,
    rate_hz: f64,
    phase_s: f64,
    jitter_std_ns: f64,
    rng: &mut rand_xoshiro::Xoshiro256PlusPlus,
) -> Vec<(f64, i64)> {
    let n = ((opts.duration_s - phase_s) * rate_hz).floor().max(0.0) as usize + 1;
    let clip = 0.4 * 1e9 / rate_hz;
    (0..n)
        .map(|k| {
            let t = phase_s + k as f64 / rate_hz;
            let jitter = if jitter_std_ns > 0.0 {
                (normal(rng) * jitter_std_ns).clamp(-clip, clip)
            } else {
                0.0
            };
            (t, opts.start_stamp_ns + (t * 1e9 + jitter).round() as i64)
        })
        .collect()
}

/// `sim.toml`: the options as a `[sim]` section (loadable as a [`pfslam::config::Config`]).
pub fn sim_toml(opts: &SimOptions) -> Result<String, SimError> {
    #[derive(Serialize)]
    struct Wrapper<'a> {
        sim: &'a SimOptions,
    }
    toml::to_string_pretty(&Wrapper { sim: opts })
        .map_err(|e| SimError::BadOption(format!("cannot serialise the options: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sim_toml_roundtrips_as_config() {
        let mut o = SimOptions::noise_free();
        o.seed = 77;
        o.world = "office".into();
        let text = sim_toml(&o).unwrap();
        let c: pfslam::config::Config = toml::from_str(&text).unwrap();
        assert_eq!(c.sim, o);
        assert!(toml::from_str::<pfslam::config::Config>("[sim]\nbogus = 1\n").is_err());
        let mut bad = SimOptions::default();
        bad.car.errors.lidar_dropout_prob = 2.0;
        assert!(bad.validate().is_err());
        assert!(SimOptions::default().validate().is_ok());
    }
}
