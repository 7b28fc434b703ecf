//! The simulator's options (`[sim]` in the configuration): which vehicle, world and
//! duration, the car's and the humanoid's rates and errors, and the scan-surface truth's
//! sampling. The simulator itself (worlds, ray casting, vehicles, true maps) is the
//! `pfslam-sim` crate's; the options live here so [`crate::Config`] holds them.

use serde::{Deserialize, Serialize};

/// A simulator option out of range, naming its key under `sim.`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("bad simulator option: {0}")]
pub struct SimOptionError(pub String);

/// Which vehicle to simulate.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Vehicle {
    /// The seed car (UCSD/KAIST): encoders, FOG, tilted SICK LMS511.
    #[default]
    Car,
    /// The humanoid (THOR): odometry poses, IMU, Hokuyo on a moving head.
    Humanoid,
}

/// Options of the simulator (`[sim]` in the configuration). `sim.toml` written beside every
/// simulated dataset holds these exactly, so `--config sim.toml` reproduces the run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimOptions {
    /// Seed of the one random generator (<= 2^63 - 1 so TOML can hold it).
    pub seed: u64,
    /// Vehicle.
    pub vehicle: Vehicle,
    /// Built-in world name or world-file path; empty = the vehicle's default world
    /// (`campus` for the car, `office` for the humanoid).
    pub world: String,
    /// Length of the recording (s). The real car recording is ~1160 s.
    pub duration_s: f64,
    /// Time of the first sample (ns since the epoch).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub start_stamp_ns: i64,
    /// Cell size of the true map (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub truth_map_resolution_m: f64,
    /// Lower end of the height band whose obstacles the car's true map shows (m); the
    /// humanoid's band is in [`HumanoidSimOptions`]. The default 1.7 m is just below the
    /// car's LiDAR (1.76 m): its beams run level sideways and rise forwards, so obstacles
    /// lower than the LiDAR (parked cars) are never hit, only overflown (the two edge beams
    /// that dip 3 deg reach the ground ~33 m to the sides).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub truth_band_min_m: f64,
    /// Upper end of that band (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub truth_band_max_m: f64,
    /// The car's scan-surface truth (`[sim.scan_truth]`, rule in `pfslam_sim::scan_truth`):
    /// written as `true_map.*` and `true_map_visible.*`; the fixed-band map above is
    /// `true_map_band.*`.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub scan_truth: ScanTruthOptions,
    /// The car (`[sim.car]`).
    pub car: CarSimOptions,
    /// The humanoid (`[sim.humanoid]`).
    pub humanoid: HumanoidSimOptions,
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions {
            seed: 1,
            vehicle: Vehicle::Car,
            world: String::new(),
            duration_s: 180.0,
            start_stamp_ns: 1_544_582_648_000_000_000,
            truth_map_resolution_m: 0.1,
            truth_band_min_m: 1.7,
            truth_band_max_m: 4.0,
            scan_truth: ScanTruthOptions::default(),
            car: CarSimOptions::default(),
            humanoid: HumanoidSimOptions::default(),
        }
    }
}

impl SimOptions {
    /// The defaults with every error switched off (see [`CarSimOptions::noise_free`]).
    pub fn noise_free() -> Self {
        SimOptions {
            car: CarSimOptions::noise_free(),
            humanoid: HumanoidSimOptions::noise_free(),
            ..SimOptions::default()
        }
    }

    /// The world to use: `world` or the vehicle's default.
    pub fn world_name(&self) -> &str {
        if !self.world.is_empty() {
            return &self.world;
        }
        match self.vehicle {
            Vehicle::Car => "campus",
            Vehicle::Humanoid => "office",
        }
    }

    /// Checks ranges (rates positive, probabilities in [0, 1], ...).
    pub fn validate(&self) -> Result<(), SimOptionError> {
        let bad = |m: &str| Err(SimOptionError(m.to_string()));
        if self.seed > i64::MAX as u64 {
            return bad("sim.seed must be <= 9223372036854775807");
        }
        if !(self.duration_s > 0.0 && self.duration_s <= 86_400.0) {
            return bad("sim.duration_s must be in (0, 86400]");
        }
        if !(self.truth_map_resolution_m >= 0.01 && self.truth_map_resolution_m <= 10.0) {
            return bad("sim.truth_map_resolution_m must be in [0.01, 10]");
        }
        if self.truth_band_max_m.is_nan() || self.truth_band_max_m < self.truth_band_min_m {
            return bad("sim.truth_band_max_m must be >= sim.truth_band_min_m");
        }
        self.scan_truth.validate()?;
        self.car.validate()?;
        self.humanoid.validate()
    }
}

/// The car's motion and sensor rates (`[sim.car]`); its errors are `[sim.car.errors]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CarSimOptions {
    /// Encoder rate (Hz); the real one is ~100 Hz.
    pub encoder_rate_hz: f64,
    /// FOG rate (Hz); the real one is ~1 kHz.
    pub fog_rate_hz: f64,
    /// LiDAR rate (Hz); the real one is ~100 Hz.
    pub lidar_rate_hz: f64,
    /// Seconds standing still before driving off.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub initial_standstill_s: f64,
    /// Cruise speed (m/s); it varies +-10 % along the route.
    pub cruise_speed_mps: f64,
    /// Longitudinal acceleration limit (m/s^2).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub max_accel_mps2: f64,
    /// Braking limit (m/s^2).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub max_decel_mps2: f64,
    /// Lateral acceleration limit in corners (m/s^2).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub max_lateral_accel_mps2: f64,
    /// Corner radius of the rounded route (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub corner_radius_m: f64,
    /// Stereo pair rate (Hz; 0 = no stereo images). Pairs are ray-cast renderings of the
    /// world (textured ground, coloured obstacles) through the real rig
    /// ([`crate::sensors::StereoCalibration::ucsd`]: 1280x560, distortion, extrinsic), written
    /// as raw 8-bit Bayer BG PNGs in `stereo_images/stereo_{left,right}/<stamp_ns>.png`. The
    /// real camera runs at ~10 Hz, but one pair costs ~1 s of rendering on 2 busy cores
    /// (~0.6 s more to match it later), hence off by default.
    pub stereo_rate_hz: f64,
    /// Rays per pixel along each image axis (1 = one ray per pixel). 2 costs 4x (~3.6 s a
    /// pair) and anti-aliases the fine ground grain, which the matcher rewards: on a 24 s
    /// drive, texture coverage 87 % -> 96 % and mean colour error 3.2 -> 2.8 (0-255).
    pub stereo_supersample: usize,
    /// The car's sensor and wheel errors.
    pub errors: CarSimErrors,
}

/// The car's sensor and wheel errors (`[sim.car.errors]`). All zero in
/// [`CarSimErrors::none`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CarSimErrors {
    /// True left wheel diameter = calibrated * (1 + this): tyre pressure, wear.
    pub left_wheel_diameter_error: f64,
    /// True right wheel diameter = calibrated * (1 + this).
    pub right_wheel_diameter_error: f64,
    /// Wheel slip: each wheel turns `1 + N(0, this^2)` times its ground travel in each encoder
    /// interval (independently per wheel and interval).
    pub wheel_slip_std: f64,
    /// Constant FOG yaw-rate bias (rad/s). ~1e-5 is a few degrees per hour.
    pub fog_yaw_bias_rad_per_s: f64,
    /// FOG white noise (angle random walk) on each axis (rad/sqrt(s)): each row's increment
    /// gets `N(0, (this * sqrt(dt))^2)`.
    pub fog_noise_rad_per_sqrt_s: f64,
    /// LiDAR range noise (m, standard deviation).
    pub lidar_range_noise_std_m: f64,
    /// Probability that a beam returns nothing (0.0) although it hit something.
    pub lidar_dropout_prob: f64,
    /// Probability that a beam reports the maximum range (80 m, i.e. "no return").
    pub lidar_max_range_prob: f64,
    /// Timestamp jitter (ns, standard deviation, clipped to +-40 % of the period so rows stay
    /// ordered): the recorded stamp differs from the true sampling time.
    pub stamp_jitter_std_ns: f64,
    /// Probability that a row of any stream is missing (a dropped FOG row loses its
    /// increments, as on a real logger).
    pub drop_row_prob: f64,
}

impl Default for CarSimOptions {
    fn default() -> Self {
        CarSimOptions {
            encoder_rate_hz: 100.0,
            fog_rate_hz: 1000.0,
            lidar_rate_hz: 100.0,
            initial_standstill_s: 2.0,
            cruise_speed_mps: 9.0,
            max_accel_mps2: 1.2,
            max_decel_mps2: 2.0,
            max_lateral_accel_mps2: 2.0,
            corner_radius_m: 9.0,
            stereo_rate_hz: 0.0,
            stereo_supersample: 1,
            errors: CarSimErrors::default(),
        }
    }
}

impl Default for CarSimErrors {
    fn default() -> Self {
        CarSimErrors {
            left_wheel_diameter_error: 0.004,
            right_wheel_diameter_error: 0.002,
            wheel_slip_std: 0.01,
            fog_yaw_bias_rad_per_s: 2e-5,
            fog_noise_rad_per_sqrt_s: 1e-4,
            lidar_range_noise_std_m: 0.02,
            lidar_dropout_prob: 0.003,
            lidar_max_range_prob: 0.001,
            stamp_jitter_std_ns: 100_000.0,
            drop_row_prob: 1e-4,
        }
    }
}

impl CarSimErrors {
    /// No error: true wheels = calibrated, no slip, perfect FOG, exact ranges, exact stamps,
    /// no dropped rows. (Encoder counts are still integers: quantisation is part of the
    /// format; counts are cumulative, so it never accumulates.)
    pub fn none() -> Self {
        CarSimErrors {
            left_wheel_diameter_error: 0.0,
            right_wheel_diameter_error: 0.0,
            wheel_slip_std: 0.0,
            fog_yaw_bias_rad_per_s: 0.0,
            fog_noise_rad_per_sqrt_s: 0.0,
            lidar_range_noise_std_m: 0.0,
            lidar_dropout_prob: 0.0,
            lidar_max_range_prob: 0.0,
            stamp_jitter_std_ns: 0.0,
            drop_row_prob: 0.0,
        }
    }

    fn validate(&self) -> Result<(), SimOptionError> {
        check_all(
            &[
                ("car.errors.wheel_slip_std", self.wheel_slip_std),
                (
                    "car.errors.fog_noise_rad_per_sqrt_s",
                    self.fog_noise_rad_per_sqrt_s,
                ),
                (
                    "car.errors.lidar_range_noise_std_m",
                    self.lidar_range_noise_std_m,
                ),
                ("car.errors.stamp_jitter_std_ns", self.stamp_jitter_std_ns),
            ],
            |v| v >= 0.0 && v.is_finite(),
            "must be >= 0",
        )?;
        check_all(
            &[
                ("car.errors.lidar_dropout_prob", self.lidar_dropout_prob),
                ("car.errors.lidar_max_range_prob", self.lidar_max_range_prob),
                ("car.errors.drop_row_prob", self.drop_row_prob),
            ],
            |v| (0.0..=1.0).contains(&v),
            "must be in [0, 1]",
        )?;
        check_all(
            &[
                (
                    "car.errors.left_wheel_diameter_error",
                    self.left_wheel_diameter_error,
                ),
                (
                    "car.errors.right_wheel_diameter_error",
                    self.right_wheel_diameter_error,
                ),
            ],
            |v| v.abs() < 0.5,
            "must be in (-0.5, 0.5)",
        )?;
        if !self.fog_yaw_bias_rad_per_s.is_finite() {
            return Err(SimOptionError(
                "sim.car.errors.fog_yaw_bias_rad_per_s must be finite".into(),
            ));
        }
        Ok(())
    }
}

impl CarSimOptions {
    /// The default motion with every error off ([`CarSimErrors::none`]).
    pub fn noise_free() -> Self {
        CarSimOptions {
            errors: CarSimErrors::none(),
            ..CarSimOptions::default()
        }
    }

    fn validate(&self) -> Result<(), SimOptionError> {
        check_all(
            &[
                ("car.encoder_rate_hz", self.encoder_rate_hz),
                ("car.fog_rate_hz", self.fog_rate_hz),
                ("car.lidar_rate_hz", self.lidar_rate_hz),
                ("car.cruise_speed_mps", self.cruise_speed_mps),
                ("car.max_accel_mps2", self.max_accel_mps2),
                ("car.max_decel_mps2", self.max_decel_mps2),
                ("car.max_lateral_accel_mps2", self.max_lateral_accel_mps2),
                ("car.corner_radius_m", self.corner_radius_m),
            ],
            |v| v > 0.0 && v.is_finite(),
            "must be positive",
        )?;
        check_all(
            &[("car.initial_standstill_s", self.initial_standstill_s)],
            |v| v >= 0.0 && v.is_finite(),
            "must be >= 0",
        )?;
        self.errors.validate()?;
        if !(self.stereo_rate_hz >= 0.0 && self.stereo_rate_hz <= 100.0) {
            return Err(SimOptionError(
                "sim.car.stereo_rate_hz must be in [0, 100] (0 = no stereo images)".into(),
            ));
        }
        if !(1..=4).contains(&self.stereo_supersample) {
            return Err(SimOptionError(
                "sim.car.stereo_supersample must be in [1, 4]".into(),
            ));
        }
        Ok(())
    }
}

/// The humanoid's walk (`[sim.humanoid]`); its head motion is `[sim.humanoid.head]`, its
/// errors `[sim.humanoid.errors]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HumanoidSimOptions {
    /// Odometry, IMU and joint rate (Hz).
    pub odometry_rate_hz: f64,
    /// LiDAR rate (Hz); the UTM-30LX scans at 40 Hz.
    pub lidar_rate_hz: f64,
    /// Walking speed (m/s).
    pub walk_speed_mps: f64,
    /// Acceleration limit (m/s^2).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub max_accel_mps2: f64,
    /// Lateral acceleration limit in turns (m/s^2).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub max_lateral_accel_mps2: f64,
    /// Corner radius of the rounded route (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub corner_radius_m: f64,
    /// Gait sway amplitude in roll and pitch of the body (rad).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub sway_amplitude_rad: f64,
    /// Step frequency (Hz) of the sway.
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub step_frequency_hz: f64,
    /// Lower end of the height band of the humanoid's true map (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub truth_band_min_m: f64,
    /// Upper end of that band (m).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub truth_band_max_m: f64,
    /// The head's motion on the neck, which carries the LiDAR.
    pub head: HumanoidSimHead,
    /// The humanoid's sensor errors.
    pub errors: HumanoidSimErrors,
}

/// The head's motion (`[sim.humanoid.head]`): the neck turns it left and right and tilts it
/// down and up, both sinusoidally.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HumanoidSimHead {
    /// Neck yaw amplitude (rad): the head looks left and right sinusoidally.
    pub neck_yaw_amplitude_rad: f64,
    /// Neck yaw period (s).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub neck_yaw_period_s: f64,
    /// Head pitch varies sinusoidally between this (rad, positive = down) ...
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub pitch_min_rad: f64,
    /// ... and this (rad): far enough down that some beams hit the floor.
    pub pitch_max_rad: f64,
    /// Head pitch period (s).
    /// A constant of the method: not read from the configuration file.
    #[serde(skip)]
    pub pitch_period_s: f64,
}

/// The humanoid's sensor errors (`[sim.humanoid.errors]`). All zero in
/// [`HumanoidSimErrors::none`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HumanoidSimErrors {
    /// Odometry distance scale error (odometry = true * (1 + this)).
    pub odometry_scale_error: f64,
    /// Odometry heading drift (rad/s).
    pub odometry_yaw_drift_rad_per_s: f64,
    /// Odometry white noise per row: on each increment's x and y (m) and yaw (rad).
    pub odometry_noise_std: f64,
    /// IMU yaw drift (rad/s).
    pub imu_yaw_drift_rad_per_s: f64,
    /// IMU white noise on roll, pitch, yaw (rad).
    pub imu_noise_std_rad: f64,
    /// Joint encoder noise (rad).
    pub joint_noise_std_rad: f64,
    /// LiDAR range noise (m).
    pub lidar_range_noise_std_m: f64,
    /// Probability that a beam returns nothing (0.0).
    pub lidar_dropout_prob: f64,
    /// Timestamp jitter (ns, standard deviation, clipped to +-40 % of the period).
    pub stamp_jitter_std_ns: f64,
}

impl Default for HumanoidSimOptions {
    fn default() -> Self {
        HumanoidSimOptions {
            odometry_rate_hz: 100.0,
            lidar_rate_hz: 40.0,
            walk_speed_mps: 0.45,
            max_accel_mps2: 0.3,
            max_lateral_accel_mps2: 0.25,
            corner_radius_m: 0.6,
            sway_amplitude_rad: 0.02,
            step_frequency_hz: 0.9,
            truth_band_min_m: 0.2,
            truth_band_max_m: 2.0,
            head: HumanoidSimHead::default(),
            errors: HumanoidSimErrors::default(),
        }
    }
}

impl Default for HumanoidSimHead {
    fn default() -> Self {
        HumanoidSimHead {
            neck_yaw_amplitude_rad: 0.5,
            neck_yaw_period_s: 9.0,
            pitch_min_rad: 0.0,
            pitch_max_rad: 0.5,
            pitch_period_s: 7.0,
        }
    }
}

impl Default for HumanoidSimErrors {
    fn default() -> Self {
        HumanoidSimErrors {
            odometry_scale_error: 0.03,
            odometry_yaw_drift_rad_per_s: 0.003,
            odometry_noise_std: 0.001,
            imu_yaw_drift_rad_per_s: 0.0003,
            imu_noise_std_rad: 0.002,
            joint_noise_std_rad: 0.001,
            lidar_range_noise_std_m: 0.01,
            lidar_dropout_prob: 0.002,
            stamp_jitter_std_ns: 200_000.0,
        }
    }
}

impl HumanoidSimErrors {
    /// No error: exact odometry, IMU, joints, ranges and stamps.
    pub fn none() -> Self {
        HumanoidSimErrors {
            odometry_scale_error: 0.0,
            odometry_yaw_drift_rad_per_s: 0.0,
            odometry_noise_std: 0.0,
            imu_yaw_drift_rad_per_s: 0.0,
            imu_noise_std_rad: 0.0,
            joint_noise_std_rad: 0.0,
            lidar_range_noise_std_m: 0.0,
            lidar_dropout_prob: 0.0,
            stamp_jitter_std_ns: 0.0,
        }
    }

    fn validate(&self) -> Result<(), SimOptionError> {
        check_all(
            &[
                (
                    "humanoid.errors.odometry_noise_std",
                    self.odometry_noise_std,
                ),
                ("humanoid.errors.imu_noise_std_rad", self.imu_noise_std_rad),
                (
                    "humanoid.errors.joint_noise_std_rad",
                    self.joint_noise_std_rad,
                ),
                (
                    "humanoid.errors.lidar_range_noise_std_m",
                    self.lidar_range_noise_std_m,
                ),
                (
                    "humanoid.errors.stamp_jitter_std_ns",
                    self.stamp_jitter_std_ns,
                ),
            ],
            |v| v >= 0.0 && v.is_finite(),
            "must be >= 0",
        )?;
        check_all(
            &[(
                "humanoid.errors.lidar_dropout_prob",
                self.lidar_dropout_prob,
            )],
            |v| (0.0..=1.0).contains(&v),
            "must be in [0, 1]",
        )
    }
}

impl HumanoidSimOptions {
    /// The default walk and head motion with every error off ([`HumanoidSimErrors::none`];
    /// the gait sway stays: it is motion, measured exactly by the IMU).
    pub fn noise_free() -> Self {
        HumanoidSimOptions {
            errors: HumanoidSimErrors::none(),
            ..HumanoidSimOptions::default()
        }
    }

    fn validate(&self) -> Result<(), SimOptionError> {
        check_all(
            &[
                ("humanoid.odometry_rate_hz", self.odometry_rate_hz),
                ("humanoid.lidar_rate_hz", self.lidar_rate_hz),
                ("humanoid.walk_speed_mps", self.walk_speed_mps),
                ("humanoid.max_accel_mps2", self.max_accel_mps2),
                (
                    "humanoid.max_lateral_accel_mps2",
                    self.max_lateral_accel_mps2,
                ),
                ("humanoid.corner_radius_m", self.corner_radius_m),
                (
                    "humanoid.head.neck_yaw_period_s",
                    self.head.neck_yaw_period_s,
                ),
                ("humanoid.head.pitch_period_s", self.head.pitch_period_s),
                ("humanoid.step_frequency_hz", self.step_frequency_hz),
            ],
            |v| v > 0.0 && v.is_finite(),
            "must be positive",
        )?;
        self.errors.validate()?;
        if self.truth_band_max_m.is_nan() || self.truth_band_max_m < self.truth_band_min_m {
            return Err(SimOptionError(
                "sim.humanoid.truth_band_max_m must be >= sim.humanoid.truth_band_min_m".into(),
            ));
        }
        Ok(())
    }
}

/// The first of `keyed` (names under `sim.`) whose value fails `ok`, as an error saying it
/// `must`.
fn check_all(
    keyed: &[(&str, f64)],
    ok: impl Fn(f64) -> bool,
    must: &str,
) -> Result<(), SimOptionError> {
    match keyed.iter().find(|(_, v)| !ok(*v)) {
        Some((k, _)) => Err(SimOptionError(format!("sim.{k} {must}"))),
        None => Ok(()),
    }
}

/// Options of the scan-surface truth (`[sim.scan_truth]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScanTruthOptions {
    /// Trace from every k-th true pose (10 = 10 Hz for the car's 100 Hz LiDAR).
    pub pose_step: usize,
    /// Which rays are traced: "sensor_beams" (the LiDAR's own beam directions: surfaces a
    /// real beam can reach) or "uniform" (every `angle_step_deg` over the fan: also surfaces
    /// between the beams, which a beam at a fixed angle never reaches while the car drives
    /// parallel to them).
    pub rays: TruthRays,
    /// Angle between traced rays (deg) when `rays = "uniform"`; the real LMS511 beams are
    /// 0.666 deg apart.
    pub angle_step_deg: f64,
    /// Beams reach this far (m, 3-D range): the mapping's `[map.scan] range_max_m`.
    pub range_max_m: f64,
}

/// The rays the scan-surface truth traces from each sampled pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TruthRays {
    /// The sensor's own beam directions (`LidarGeometry`), as the LiDAR fires them.
    SensorBeams,
    /// Rays every `angle_step_deg` over the sensor's fan.
    Uniform,
}

impl Default for ScanTruthOptions {
    fn default() -> Self {
        ScanTruthOptions {
            pose_step: 10,
            rays: TruthRays::SensorBeams,
            angle_step_deg: 0.1,
            range_max_m: 75.0,
        }
    }
}

impl ScanTruthOptions {
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), SimOptionError> {
        if self.pose_step == 0 {
            return Err(SimOptionError(
                "sim.scan_truth.pose_step must be >= 1".into(),
            ));
        }
        if !(0.01..=10.0).contains(&self.angle_step_deg) {
            return Err(SimOptionError(
                "sim.scan_truth.angle_step_deg must be in [0.01, 10]".into(),
            ));
        }
        if !(self.range_max_m > 0.0 && self.range_max_m.is_finite() && self.range_max_m <= 1000.0) {
            return Err(SimOptionError(
                "sim.scan_truth.range_max_m must be in (0, 1000]".into(),
            ));
        }
        Ok(())
    }
}
