//! Walking an odometry trajectory scan by scan: the odometry steps between two scan stamps,
//! ending on the (interpolated) odometry pose at the scan.

use crate::geometry::{StampedPose2, Trajectory};

/// A cursor over an odometry trajectory that yields its steps up to successive stamps.
#[derive(Debug, Clone)]
pub struct OdometryCursor {
    /// Index of the next odometry pose not yet consumed.
    next: usize,
    /// The pose the next step starts from.
    last: StampedPose2,
}

impl OdometryCursor {
    /// A cursor positioned at `stamp_ns` (must lie inside the trajectory's span; `None`
    /// otherwise).
    pub fn new(odometry: &Trajectory, stamp_ns: i64) -> Option<Self> {
        let pose = odometry.pose_at(stamp_ns)?;
        let next = odometry.poses.partition_point(|p| p.stamp_ns <= stamp_ns);
        Some(OdometryCursor {
            next,
            last: StampedPose2 { stamp_ns, pose },
        })
    }

    /// Lets go of the odometry poses the cursor has passed (all but the last), for a
    /// trajectory that will be kept from that pose on; returns how many to drop from its
    /// front.
    pub fn forget_passed(&mut self) -> usize {
        let dropped = self.next.saturating_sub(1);
        self.next -= dropped;
        dropped
    }

    /// The odometry pose the cursor stands on.
    pub fn current(&self) -> StampedPose2 {
        self.last
    }

    /// Advances to `stamp_ns`, calling `step(from, to)` for each odometry interval crossed:
    /// every recorded pose in `(current, stamp_ns]`, then the interpolated pose at
    /// `stamp_ns` when it is not itself recorded. Returns the odometry pose at `stamp_ns`, or
    /// `None` (cursor unchanged) when `stamp_ns` is before the cursor or after the trajectory.
    pub fn advance_to<F>(
        &mut self,
        odometry: &Trajectory,
        stamp_ns: i64,
        mut step: F,
    ) -> Option<StampedPose2>
    where
        F: FnMut(&StampedPose2, &StampedPose2),
    {
        if stamp_ns < self.last.stamp_ns {
            return None;
        }
        let target = StampedPose2 {
            stamp_ns,
            pose: odometry.pose_at(stamp_ns)?,
        };
        let poses = &odometry.poses;
        while self.next < poses.len() && poses[self.next].stamp_ns <= stamp_ns {
            let to = poses[self.next];
            if to.stamp_ns > self.last.stamp_ns {
                step(&self.last, &to);
                self.last = to;
            }
            self.next += 1;
        }
        if self.last.stamp_ns < stamp_ns {
            step(&self.last, &target);
            self.last = target;
        }
        Some(self.last)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose2;

    fn traj() -> Trajectory {
        Trajectory::new(
            (0..5)
                .map(|k| StampedPose2 {
                    stamp_ns: k * 10,
                    pose: Pose2::new(k as f64, 0.0, 0.0),
                })
                .collect(),
        )
    }

    #[test]
    fn steps_cover_the_interval_exactly() {
        let t = traj();
        let mut c = OdometryCursor::new(&t, 5).unwrap();
        let mut steps = Vec::new();
        let p = c
            .advance_to(&t, 27, |a, b| steps.push((a.stamp_ns, b.stamp_ns)))
            .unwrap();
        assert_eq!(steps, vec![(5, 10), (10, 20), (20, 27)]);
        assert!((p.pose.x_m - 2.7).abs() < 1e-12);
        steps.clear();
        c.advance_to(&t, 30, |a, b| steps.push((a.stamp_ns, b.stamp_ns)));
        assert_eq!(steps, vec![(27, 30)]);
        steps.clear();
        c.advance_to(&t, 30, |a, b| steps.push((a.stamp_ns, b.stamp_ns)));
        assert!(steps.is_empty());
        assert!(c.advance_to(&t, 41, |_, _| {}).is_none());
        assert!(c.advance_to(&t, 29, |_, _| {}).is_none());
        assert_eq!(c.current().stamp_ns, 30);
    }
}
