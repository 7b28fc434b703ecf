//! How far the odometry's clock is off the scans': estimated from the filter's trajectory.
//!
//! An odometry stamped `lag` early makes every increment's yaw wrong by about
//! `lag * (rate at the end - rate at the start)`: small on straight runs, degrees where the
//! robot weaves. So the filter's yaw corrections (its yaw change over a window minus the
//! odometry's) are regressed on the odometry's change of yaw rate over the same window; the
//! slope is the lag. Where it is notable, [`run_timed`] runs again on the odometry shifted
//! by it; `[input] odometry_shift_s` sets the shift instead.

use crate::geometry::{StampedPose2, Trajectory, wrap_angle};
use crate::sensors::Recording;
use serde::Serialize;

/// Shortest window between two trajectory poses (s): long enough for the rate to change.
const WINDOW_S: f64 = 0.5;
/// The span over which the odometry's yaw rate is taken at a window's ends (s).
const RATE_SPAN_S: f64 = 0.1;
/// Corrections beyond this (rad, 20 deg) are a lost filter or a jump, not timing.
const MAX_CORRECTION_RAD: f64 = 0.349;
/// Fewest windows for an estimate.
const MIN_WINDOWS: usize = 50;
/// Share of the corrections' variance the lag must explain to be reported as a warning.
pub const NOTABLE_EXPLAINED: f64 = 0.2;
/// Smallest lag worth a warning (s).
pub const NOTABLE_LAG_S: f64 = 0.02;

/// The estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct OdometryTiming {
    /// The odometry's stamps are this much early against the scans (s; negative: late).
    /// Adding it to the odometry's stamps (`[input] odometry_shift_s`) undoes it.
    pub lag_s: f64,
    /// The estimate's standard error (s).
    pub standard_error_s: f64,
    /// Share of the filter's yaw corrections' variance the lag explains (0-1).
    pub explained: f64,
    /// Windows used.
    pub windows: usize,
}

impl OdometryTiming {
    /// True when the lag is large enough and explains enough to tell the user.
    pub fn notable(&self) -> bool {
        self.lag_s.abs() >= NOTABLE_LAG_S && self.explained >= NOTABLE_EXPLAINED
    }
}

/// The lag of `odometry` against `trajectory` (the filter's poses at the scans), or `None`
/// with too few windows or no change of turning rate to measure it by.
pub fn estimate_odometry_lag(
    odometry: &Trajectory,
    trajectory: &[StampedPose2],
) -> Option<OdometryTiming> {
    let samples = corrections(odometry, trajectory);
    if samples.len() < MIN_WINDOWS {
        return None;
    }
    let sxy: f64 = samples.iter().map(|(c, dw)| c * dw).sum();
    let syy: f64 = samples.iter().map(|(_, dw)| dw * dw).sum();
    let scc: f64 = samples.iter().map(|(c, _)| c * c).sum();
    if syy <= 0.0 || scc <= 0.0 {
        return None;
    }
    let lag_s = -sxy / syy;
    let rss: f64 = samples.iter().map(|(c, dw)| (c + lag_s * dw).powi(2)).sum();
    let n = samples.len();
    Some(OdometryTiming {
        lag_s,
        standard_error_s: (rss / (n - 1) as f64 / syy).sqrt(),
        explained: 1.0 - rss / scc,
        windows: n,
    })
}

/// Per window of at least [`WINDOW_S`] between trajectory poses: the filter's yaw
/// correction (rad) and the odometry's change of yaw rate (rad/s) over it.
fn corrections(odometry: &Trajectory, trajectory: &[StampedPose2]) -> Vec<(f64, f64)> {
    let yaw = |t: i64| odometry.pose_at(t).map(|p| p.yaw_rad);
    let span_ns = (RATE_SPAN_S * 1e9) as i64;
    let rate = |t: i64| Some(wrap_angle(yaw(t)? - yaw(t - span_ns)?) / RATE_SPAN_S);
    let window_ns = (WINDOW_S * 1e9) as i64;
    let mut out = Vec::new();
    let mut i = 0;
    while i < trajectory.len() {
        let a = &trajectory[i];
        let Some(j) =
            (i + 1..trajectory.len()).find(|&j| trajectory[j].stamp_ns - a.stamp_ns >= window_ns)
        else {
            break;
        };
        let b = &trajectory[j];
        let sample = (|| {
            let odo = wrap_angle(yaw(b.stamp_ns)? - yaw(a.stamp_ns)?);
            let c = wrap_angle(wrap_angle(b.pose.yaw_rad - a.pose.yaw_rad) - odo);
            let dw = rate(b.stamp_ns)? - rate(a.stamp_ns)?;
            (c.abs() <= MAX_CORRECTION_RAD).then_some((c, dw))
        })();
        out.extend(sample);
        i = j;
    }
    out
}

/// The odometry's timing in a run: its lag as measured from the filter's trajectory, the
/// shift applied to its stamps, and the lag left after it.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct OdometryTimingReport {
    /// The lag measured on the filter's first run (none when too little turning).
    pub measured: Option<OdometryTiming>,
    /// The shift added to the odometry's stamps (s): `[input] odometry_shift_s`, or the
    /// measured lag when that is unset and the lag notable (the filter then ran again).
    pub shift_s: f64,
    /// The filter ran again on the shifted odometry.
    pub rerun: bool,
    /// The lag measured on the filter's run over the shifted odometry, when it ran again.
    pub after_shift: Option<OdometryTiming>,
    /// Wall seconds of that second run (0 without).
    pub rerun_s: f64,
}

/// `recording` with the odometry shifted by `shift_s` (`[input] odometry_shift_s`), when
/// set and not 0.
pub fn fixed_shift(recording: &Recording, shift_s: Option<f64>) -> Option<Recording> {
    let shift_s = shift_s.filter(|&s| s != 0.0)?;
    let mut shifted = recording.clone();
    shift_odometry(&mut shifted, shift_s);
    Some(shifted)
}

/// A shift (s) in whole nanoseconds, as added to odometry stamps.
pub fn shift_ns(shift_s: f64) -> i64 {
    (shift_s * 1e9).round() as i64
}

/// Moves every odometry stamp of `recording` by `shift_s`.
pub fn shift_odometry(recording: &mut Recording, shift_s: f64) {
    let shift_ns = shift_ns(shift_s);
    for p in &mut recording.odometry.poses {
        p.stamp_ns = p.stamp_ns.saturating_add(shift_ns);
    }
}

/// The odometry's lag against the filter's trajectory, with a warning when it is notable.
fn measure_lag(recording: &Recording, front_end: &[StampedPose2]) -> Option<OdometryTiming> {
    let timing = estimate_odometry_lag(&recording.odometry, front_end)?;
    if timing.notable() {
        tracing::warn!(
            "the odometry's stamps look {:.0} ms {} against the scans' (+-{:.0} ms; it explains \
             {:.0} % of the filter's yaw corrections)",
            timing.lag_s.abs() * 1e3,
            if timing.lag_s > 0.0 { "early" } else { "late" },
            timing.standard_error_s * 1e3,
            timing.explained * 100.0,
        );
    }
    Some(timing)
}

/// Fills `report` from a run's `trajectory` on `recording`, whose odometry was shifted by
/// `shift_s` (`[input] odometry_shift_s`); returns the lag to run again with when that is
/// unset and the lag is notable.
fn lag_to_rerun(
    recording: &Recording,
    shift_s: Option<f64>,
    trajectory: &[StampedPose2],
    report: &mut OdometryTimingReport,
) -> Option<f64> {
    report.shift_s = shift_s.unwrap_or(0.0);
    report.measured = measure_lag(recording, trajectory);
    match (shift_s, report.measured) {
        (None, Some(t)) if t.notable() => {
            tracing::info!(
                "running the filter again on the odometry shifted by {:.3} s",
                t.lag_s
            );
            report.shift_s = t.lag_s;
            report.rerun = true;
            Some(t.lag_s)
        }
        _ => None,
    }
}

/// The timing of a `first` run on `recording` (its odometry shifted by `shift_s`, the run's
/// `[input] odometry_shift_s`) and, when `shift_s` is unset and the lag measured on the
/// run's `trajectory` is notable, `run` again on the odometry shifted by that lag: the
/// shifted recording and the second result.
pub fn rerun_if_lagged<T, E>(
    recording: &Recording,
    shift_s: Option<f64>,
    first: &T,
    trajectory: impl Fn(&T) -> &[StampedPose2],
    run: impl FnOnce(&Recording) -> Result<T, E>,
) -> Result<(OdometryTimingReport, Option<(Recording, T)>), E> {
    let mut report = OdometryTimingReport::default();
    let Some(lag) = lag_to_rerun(recording, shift_s, trajectory(first), &mut report) else {
        return Ok((report, None));
    };
    let t = std::time::Instant::now();
    let mut shifted = recording.clone();
    shift_odometry(&mut shifted, lag);
    let again = run(&shifted)?;
    report.rerun_s = t.elapsed().as_secs_f64();
    report.after_shift = estimate_odometry_lag(&shifted.odometry, trajectory(&again));
    Ok((report, Some((shifted, again))))
}

/// Runs `run` on `recording` (its odometry shifted by `shift_s` when set and not 0), then
/// [`rerun_if_lagged`]; the result kept and the timing. `run`'s flag is true on the first
/// run.
pub fn run_timed<T, E>(
    recording: &Recording,
    shift_s: Option<f64>,
    mut run: impl FnMut(&Recording, bool) -> Result<T, E>,
    trajectory: impl Fn(&T) -> &[StampedPose2],
) -> Result<(T, OdometryTimingReport), E> {
    let fixed = fixed_shift(recording, shift_s);
    let recording = fixed.as_ref().unwrap_or(recording);
    let first = run(recording, true)?;
    let again = |rec: &Recording| run(rec, false);
    let (report, rerun) = rerun_if_lagged(recording, shift_s, &first, trajectory, again)?;
    Ok((rerun.map_or(first, |(_, again)| again), report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose2;

    /// A robot weaving (yaw a sum of two sines) for 120 s: its poses every 0.1 s, and its
    /// odometry stamped `lag_s` early with a small yaw noise from a fixed sequence.
    fn weave(lag_s: f64) -> (Trajectory, Vec<StampedPose2>) {
        let yaw = |t: f64| 0.6 * (0.9 * t).sin() + 0.3 * (2.3 * t + 1.0).sin();
        let mut odometry = Vec::new();
        let mut truth = Vec::new();
        for k in 0..1200 {
            let t = 0.1 * f64::from(k);
            let stamp_ns = (t * 1e9) as i64;
            let noise = 0.002 * (f64::from(k) * 12.9898).sin();
            let pose = |y: f64| Pose2::new(0.1 * t, 0.0, wrap_angle(y));
            odometry.push(StampedPose2 {
                stamp_ns,
                pose: pose(yaw(t + lag_s) + noise),
            });
            truth.push(StampedPose2 {
                stamp_ns,
                pose: pose(yaw(t)),
            });
        }
        (Trajectory::new(odometry), truth)
    }

    #[test]
    fn an_odometry_stamped_early_is_measured_by_its_lag() {
        let (odometry, truth) = weave(0.1);
        let timing = estimate_odometry_lag(&odometry, &truth).expect("enough windows");
        assert!((timing.lag_s - 0.1).abs() < 0.01, "{timing:?}");
        assert!(timing.explained > 0.9 && timing.notable(), "{timing:?}");
    }

    #[test]
    fn an_odometry_on_time_shows_no_notable_lag() {
        let (odometry, truth) = weave(0.0);
        let timing = estimate_odometry_lag(&odometry, &truth).expect("enough windows");
        assert!(timing.lag_s.abs() < 0.01, "{timing:?}");
        assert!(!timing.notable(), "{timing:?}");
    }

    #[test]
    fn a_straight_drive_gives_no_estimate() {
        let poses: Vec<StampedPose2> = (0..1200)
            .map(|k| StampedPose2 {
                stamp_ns: i64::from(k) * 100_000_000,
                pose: Pose2::new(0.1 * f64::from(k), 0.0, 0.0),
            })
            .collect();
        let odometry = Trajectory::new(poses.clone());
        assert!(estimate_odometry_lag(&odometry, &poses).is_none());
    }
}
