//! Stale scans: a scan that repeats one taken seconds earlier although the odometry moved
//! since. Some drivers and bridges re-publish an old buffer or deliver a scan late under a
//! new stamp (the Intel bag holds about a hundred among 13,600); placed at its stamp, such a scan
//! drags a filter back to where it was taken and smears the map.
//!
//! The test is relative, so it needs no noise model of the sensor: a fresh scan resembles
//! its immediate predecessors at least as much as any older scan (at rest, in a corridor, on
//! an interlaced scanner alike), a stale one resembles an older scan far more than them.

use crate::geometry::{Pose2, wrap_angle};
use crate::sensors::LidarGeometry;
use std::collections::VecDeque;

/// Scans this recent (ns) are compared with: drivers deliver late by seconds, not more (the
/// Intel bag's repeats are 0.2-8.6 s old), and at keyframe rates no older scan is in reach.
const RECENT_NS: i64 = 10_000_000_000;
/// At most this many recent scans (a 25 Hz scanner's 10 s), to bound the cost.
const RECENT_MAX: usize = 256;
/// Two ranges of one bearing agree within this (m): a few times a scanner's noise at rest.
const AGREE_M: f32 = 0.02;
/// A stale scan agrees with an older scan on at least this share of the bearings valid in
/// both...
const MIN_SHARE: f64 = 0.5;
/// ...and this many times more than with either of the two scans before it.
const MIN_RATIO: f64 = 2.0;
/// The odometry moved this far (m) or turned this much (deg) since that older scan: at rest
/// repeated scans are the truth.
const MOVED: (f64, f64) = (0.2, 5.0);

/// A scan kept for comparison.
#[derive(Debug, Clone)]
struct Kept {
    stamp_ns: i64,
    ranges_m: Vec<f32>,
    lidar: LidarGeometry,
    odom: Pose2,
}

/// The recent scans and the test (see the module).
#[derive(Debug, Clone, Default)]
pub struct StaleScans {
    recent: VecDeque<Kept>,
}

impl StaleScans {
    /// True when the scan `ranges_m` with beams `lidar`, at odometry pose `odom`, is stale;
    /// a scan that is not is kept for the next tests.
    pub fn check(
        &mut self,
        stamp_ns: i64,
        ranges_m: &[f32],
        lidar: &LidarGeometry,
        odom: &Pose2,
    ) -> bool {
        while self.recent.len() >= RECENT_MAX
            || self
                .recent
                .front()
                .is_some_and(|k| stamp_ns - k.stamp_ns > RECENT_NS)
        {
            self.recent.pop_front();
        }
        let n = self.recent.len();
        if n >= 3 {
            let share = |k: &Kept, at_least: f64| agreement(ranges_m, lidar, k, at_least);
            let latest = share(&self.recent[n - 1], 0.0).max(share(&self.recent[n - 2], 0.0));
            let needed = MIN_SHARE.max(MIN_RATIO * latest);
            let older = self
                .recent
                .iter()
                .take(n - 2)
                .map(|k| (share(k, needed), k));
            if let Some((best, kept)) = older.max_by(|a, b| a.0.total_cmp(&b.0))
                && best >= MIN_SHARE
                && best >= MIN_RATIO * latest
                && moved(&kept.odom, odom)
            {
                return true;
            }
        }
        self.recent.push_back(Kept {
            stamp_ns,
            ranges_m: ranges_m.to_vec(),
            lidar: *lidar,
            odom: *odom,
        });
        false
    }
}

/// The share of the bearings with a return in both scans where the two ranges agree (0 for
/// scans of other beam layouts); -1 as soon as the share cannot reach `at_least` (most
/// comparisons end halfway).
fn agreement(ranges_m: &[f32], lidar: &LidarGeometry, kept: &Kept, at_least: f64) -> f64 {
    if kept.lidar != *lidar || kept.ranges_m.len() != ranges_m.len() {
        return 0.0;
    }
    let valid = |r: f32| r > lidar.range_min_m && r < lidar.range_max_m;
    let (mut both, mut agree) = (0usize, 0usize);
    let pairs = ranges_m.chunks(32).zip(kept.ranges_m.chunks(32));
    let mut left = ranges_m.len();
    for (new, old) in pairs {
        for (&a, &b) in new.iter().zip(old) {
            if valid(a) && valid(b) {
                both += 1;
                agree += usize::from((a - b).abs() < AGREE_M);
            }
        }
        left -= new.len();
        // The best share left: every remaining bearing valid in both and agreeing (a
        // margin of 1e-9 keeps rounding from ending a comparison that could reach it).
        if ((agree + left) as f64) < at_least * (1.0 - 1e-9) * (both + left) as f64 {
            return -1.0;
        }
    }
    agree as f64 / both.max(1) as f64
}

fn moved(from: &Pose2, to: &Pose2) -> bool {
    let d = from.between(to);
    d.translation_norm_m() > MOVED.0 || wrap_angle(d.yaw_rad).abs() > MOVED.1.to_radians()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lidar() -> LidarGeometry {
        LidarGeometry {
            angle_min_rad: -std::f64::consts::FRAC_PI_2,
            angle_increment_rad: std::f64::consts::PI / 180.0,
            beam_count: 181,
            range_min_m: 0.0,
            range_max_m: 50.0,
        }
    }

    /// The stamp of scan `k` at 10 Hz.
    fn at(k: i32) -> i64 {
        i64::from(k) * 100_000_000
    }

    /// Ranges of a room seen from heading `yaw_deg` (whole degrees), with a per-scan ripple.
    fn room(yaw_deg: i32, ripple: u32) -> Vec<f32> {
        (0..181)
            .map(|b| {
                let a = ((b + yaw_deg).rem_euclid(360)) as f32;
                let noise = (((b as u32 * 7919 + ripple * 104_729) % 11) as f32 - 5.0) * 0.004;
                4.0 + 2.0 * (a.to_radians() * 3.0).sin() + noise
            })
            .collect()
    }

    #[test]
    fn a_repeated_scan_after_a_turn_is_stale_and_fresh_scans_are_not() {
        let mut stale = StaleScans::default();
        let l = lidar();
        // Turning 3 deg per scan: every scan fresh.
        for k in 0..10 {
            let odom = Pose2::new(0.0, 0.0, f64::from(3 * k).to_radians());
            assert!(
                !stale.check(at(k), &room(3 * k, k as u32), &l, &odom),
                "scan {k}"
            );
        }
        // The scan of the second step again, the odometry 27 deg further on.
        let odom = Pose2::new(0.0, 0.0, 30f64.to_radians());
        assert!(stale.check(at(10), &room(3, 1), &l, &odom));
        // The turn goes on: fresh again.
        assert!(!stale.check(at(11), &room(30, 10), &l, &odom));
    }

    #[test]
    fn a_scan_repeated_after_seconds_is_not_compared_any_more() {
        // Keyframes 5 s apart: the scans before the latest two are out of reach.
        let mut stale = StaleScans::default();
        let l = lidar();
        for k in 0..10 {
            let odom = Pose2::new(0.0, 0.0, f64::from(3 * k).to_radians());
            assert!(!stale.check(at(50 * k), &room(3 * k, k as u32), &l, &odom));
        }
        let odom = Pose2::new(0.0, 0.0, 30f64.to_radians());
        assert!(!stale.check(at(500), &room(3 * 7, 7), &l, &odom));
    }

    #[test]
    fn repeated_scans_at_rest_and_interlaced_scans_are_not_stale() {
        let mut stale = StaleScans::default();
        let l = lidar();
        // At rest, two interleaved patterns (an interlaced scanner): the scan two back
        // agrees, the one before does not; the odometry creeps (wheel slip) past the limit.
        for k in 0..60 {
            let odom = Pose2::new(0.01 * f64::from(k), 0.0, 0.0);
            assert!(!stale.check(at(k), &room(k % 2, 0), &l, &odom), "scan {k}");
        }
    }
}
