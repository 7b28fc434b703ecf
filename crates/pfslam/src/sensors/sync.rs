//! Synchronisation of the car's three streams.
//!
//! - [`merge_events`]: one time-ordered sequence of encoder, FOG and LiDAR events.
//! - [`CumulativeYaw`]: FOG yaw increments integrated **by timestamp**. Row `i` of `fog.csv`
//!   holds the rotation over `(t_{i-1}, t_i]`; it is spread uniformly over that interval, so
//!   the cumulative yaw is piecewise linear through the knots `(t_i, sum_{j<=i} delta_j)`. The
//!   yaw between any two instants (e.g. consecutive encoder stamps) is a difference of two
//!   evaluations: a row straddling an encoder stamp is split in proportion to time, a dropped
//!   row makes the next row's interval (and increment) longer, jitter needs no special case.
//!   (The seed summed "every 11 rows", which drifts as soon as the rates are not an exact
//!   ratio.) The first row's interval begins at an unknown time before the recording, so its
//!   increment is not used: the covered span starts at the first row's stamp.
//! - [`poses_at_stamps`]: poses at arbitrary stamps (LiDAR scans) by interpolation.

use super::CarDataset;
use crate::geometry::{StampedPose2, Trajectory};

/// Which stream an event comes from, with the row index in the [`CarDataset`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SensorEvent {
    /// `ds.fog[i]`.
    Fog(usize),
    /// `ds.encoder[i]`.
    Encoder(usize),
    /// Scan `i` of `ds.lidar`.
    Lidar(usize),
}

/// An event and its time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimedEvent {
    /// Time (ns).
    pub stamp_ns: i64,
    /// What happened.
    pub event: SensorEvent,
}

/// Merges the three (individually time-ordered) streams into one time-ordered sequence. At
/// equal stamps the order is FOG, encoder, LiDAR: a FOG increment ending at `t` belongs to
/// the motion up to `t`, and a scan at `t` should see the pose at `t`.
pub fn merge_events(ds: &CarDataset) -> Vec<TimedEvent> {
    let (mut i, mut j, mut k) = (0usize, 0usize, 0usize);
    let (nf, ne, nl) = (ds.fog.len(), ds.encoder.len(), ds.lidar.len());
    let mut out = Vec::with_capacity(nf + ne + nl);
    loop {
        let tf = ds.fog.get(i).map(|s| s.stamp_ns);
        let te = ds.encoder.get(j).map(|s| s.stamp_ns);
        let tl = ds.lidar.stamps_ns.get(k).copied();
        let best = [tf, te, tl]
            .iter()
            .enumerate()
            .filter_map(|(n, t)| t.map(|t| (t, n)))
            .min();
        let Some((stamp_ns, which)) = best else {
            break;
        };
        let event = match which {
            0 => {
                i += 1;
                SensorEvent::Fog(i - 1)
            }
            1 => {
                j += 1;
                SensorEvent::Encoder(j - 1)
            }
            _ => {
                k += 1;
                SensorEvent::Lidar(k - 1)
            }
        };
        out.push(TimedEvent { stamp_ns, event });
    }
    out
}

/// The FOG's cumulative yaw as a piecewise-linear function of time (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct CumulativeYaw {
    /// Knot times (ns), strictly increasing: the FOG rows' stamps.
    stamps_ns: Vec<i64>,
    /// Cumulative yaw at the knots (rad), 0 at the first knot.
    yaw_rad: Vec<f64>,
    /// Median spacing of the FOG rows (ns).
    median_period_ns: i64,
    /// Longest spacing between consecutive FOG rows (ns).
    max_gap_ns: i64,
}

impl CumulativeYaw {
    /// Builds the function from FOG rows (time ordered, strictly increasing stamps); `None`
    /// when there is no row or the stamps do not increase.
    pub fn from_fog(fog: &[super::FogSample]) -> Option<CumulativeYaw> {
        let first = fog.first()?;
        if fog.windows(2).any(|w| w[1].stamp_ns <= w[0].stamp_ns) {
            return None;
        }
        let mut periods: Vec<i64> = fog
            .windows(2)
            .take(1001)
            .map(|w| w[1].stamp_ns - w[0].stamp_ns)
            .collect();
        periods.sort_unstable();
        let median_period_ns = periods.get(periods.len() / 2).copied().unwrap_or(1).max(1);
        let max_gap_ns = fog
            .windows(2)
            .map(|w| w[1].stamp_ns - w[0].stamp_ns)
            .max()
            .unwrap_or(0);
        let mut stamps_ns = Vec::with_capacity(fog.len());
        let mut yaw_rad = Vec::with_capacity(fog.len());
        stamps_ns.push(first.stamp_ns);
        yaw_rad.push(0.0);
        let mut sum = 0.0;
        for s in &fog[1..] {
            sum += s.delta_yaw_rad;
            stamps_ns.push(s.stamp_ns);
            yaw_rad.push(sum);
        }
        Some(CumulativeYaw {
            stamps_ns,
            yaw_rad,
            median_period_ns,
            max_gap_ns,
        })
    }

    /// Start of the time span covered by FOG rows: the first row's stamp (ns).
    pub fn start_ns(&self) -> i64 {
        self.stamps_ns[0]
    }

    /// End of the covered span: the last row's stamp (ns).
    pub fn end_ns(&self) -> i64 {
        self.stamps_ns[self.stamps_ns.len() - 1]
    }

    /// Median FOG row spacing (ns).
    pub fn median_period_ns(&self) -> i64 {
        self.median_period_ns
    }

    /// Longest spacing between rows (ns): far above the median means dropped rows, whose
    /// rotation the next row's increment spreads uniformly over the gap.
    pub fn max_gap_ns(&self) -> i64 {
        self.max_gap_ns
    }

    /// Cumulative yaw at `stamp_ns` (rad): linear between knots, constant outside the span.
    pub fn yaw_at(&self, stamp_ns: i64) -> f64 {
        let s = &self.stamps_ns;
        if stamp_ns <= s[0] {
            return self.yaw_rad[0];
        }
        let n = s.len();
        if stamp_ns >= s[n - 1] {
            return self.yaw_rad[n - 1];
        }
        // s[i-1] < stamp <= s[i]
        let i = s.partition_point(|&t| t < stamp_ns);
        let (t0, t1) = (s[i - 1], s[i]);
        let (y0, y1) = (self.yaw_rad[i - 1], self.yaw_rad[i]);
        if stamp_ns == t1 {
            return y1;
        }
        y0 + (y1 - y0) * ((stamp_ns - t0) as f64 / (t1 - t0) as f64)
    }

    /// Yaw rotation over `(from_ns, to_ns]` (rad).
    pub fn increment(&self, from_ns: i64, to_ns: i64) -> f64 {
        self.yaw_at(to_ns) - self.yaw_at(from_ns)
    }

    /// True when `(from_ns, to_ns]` lies inside the covered span.
    pub fn covers(&self, from_ns: i64, to_ns: i64) -> bool {
        from_ns >= self.start_ns() && to_ns <= self.end_ns()
    }
}

/// Poses at `stamps_ns` (sorted) interpolated on `traj` (linear position, shortest-arc yaw).
/// Stamps outside the trajectory's span get its first / last pose; the second value counts
/// them.
pub fn poses_at_stamps(traj: &Trajectory, stamps_ns: &[i64]) -> (Vec<StampedPose2>, usize) {
    let mut clamped = 0usize;
    let (Some(first), Some(last)) = (traj.poses.first(), traj.poses.last()) else {
        return (Vec::new(), stamps_ns.len());
    };
    let out = stamps_ns
        .iter()
        .map(|&t| {
            let pose = traj.pose_at(t).unwrap_or_else(|| {
                clamped += 1;
                if t < first.stamp_ns {
                    first.pose
                } else {
                    last.pose
                }
            });
            StampedPose2 { stamp_ns: t, pose }
        })
        .collect();
    (out, clamped)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::FogSample;

    fn fog(rows: &[(i64, f64)]) -> Vec<FogSample> {
        rows.iter()
            .map(|&(t, d)| FogSample {
                stamp_ns: t,
                delta_roll_rad: 0.0,
                delta_pitch_rad: 0.0,
                delta_yaw_rad: d,
            })
            .collect()
    }

    #[test]
    fn straddling_row_is_split_by_time() {
        // Rows every 10 ns; the row at 30 covers (20, 30] with 0.3 rad. The first row's
        // increment (its interval starts before the span) is not used.
        let y =
            CumulativeYaw::from_fog(&fog(&[(10, 0.7), (20, 0.1), (30, 0.3), (40, 0.1)])).unwrap();
        assert_eq!(y.start_ns(), 10);
        // (10, 25]: 0.1 + half of 0.3
        assert!((y.increment(10, 25) - 0.25).abs() < 1e-15);
        // (25, 40]: other half + 0.1
        assert!((y.increment(25, 40) - 0.25).abs() < 1e-15);
    }

    #[test]
    fn dropped_rows_spread_over_the_gap() {
        // Rows at 10, 20, then 50 (two rows dropped): 0.3 covers (20, 50].
        let y = CumulativeYaw::from_fog(&fog(&[(10, 0.1), (20, 0.1), (50, 0.3)])).unwrap();
        assert!((y.increment(20, 30) - 0.1).abs() < 1e-15);
        assert!((y.increment(30, 50) - 0.2).abs() < 1e-15);
        assert_eq!(y.max_gap_ns(), 30);
        assert!(y.covers(10, 50) && !y.covers(10, 51) && !y.covers(9, 50));
    }

    #[test]
    fn merge_orders_streams() {
        let mut ds = CarDataset {
            calibration: crate::sensors::CarCalibration::ucsd(),
            encoder: vec![],
            fog: fog(&[(5, 0.0), (10, 0.0)]),
            lidar: crate::sensors::ScanSet::new(1),
            stereo_stamps_ns: vec![],
        };
        ds.encoder.push(crate::sensors::EncoderSample {
            stamp_ns: 10,
            left_count: 0,
            right_count: 0,
        });
        ds.lidar.push(7, &[1.0]);
        ds.lidar.push(10, &[1.0]);
        let ev: Vec<SensorEvent> = merge_events(&ds).iter().map(|e| e.event).collect();
        assert_eq!(
            ev,
            vec![
                SensorEvent::Fog(0),
                SensorEvent::Lidar(0),
                SensorEvent::Fog(1),
                SensorEvent::Encoder(0),
                SensorEvent::Lidar(1)
            ]
        );
    }
}
