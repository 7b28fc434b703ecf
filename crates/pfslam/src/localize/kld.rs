//! KLD sampling (Fox, 2003): how many particles a resampled set needs so that, with
//! probability `1 - delta`, the Kullback-Leibler distance between the sample and the true
//! posterior stays under `epsilon`, given the number `k` of histogram bins the sample
//! occupies so far.

use crate::geometry::{Pose2, wrap_angle};
use std::collections::HashSet;

/// The sample size bound for `k` occupied bins (Wilson-Hilferty approximation of the
/// chi-square quantile); `z` is the upper standard normal quantile of `1 - delta`.
pub fn kld_bound(k: usize, epsilon: f64, z: f64) -> usize {
    if k <= 1 {
        return 1;
    }
    let km1 = (k - 1) as f64;
    let a = 2.0 / (9.0 * km1);
    let cube = (1.0 - a + a.sqrt() * z).powi(3);
    (km1 / (2.0 * epsilon) * cube).ceil() as usize
}

/// The histogram's occupied bins.
#[derive(Debug, Clone)]
pub struct KldBins {
    inv_xy: f64,
    inv_yaw: f64,
    occupied: HashSet<(i32, i32, i32)>,
}

impl KldBins {
    /// Bins of `xy_m` by `xy_m` by `yaw_rad`.
    pub fn new(xy_m: f64, yaw_rad: f64) -> Self {
        KldBins {
            inv_xy: 1.0 / xy_m,
            inv_yaw: 1.0 / yaw_rad,
            occupied: HashSet::new(),
        }
    }

    /// Empties the histogram.
    pub fn clear(&mut self) {
        self.occupied.clear();
    }

    /// Adds a pose; returns the number of occupied bins.
    pub fn add(&mut self, pose: &Pose2) -> usize {
        let key = (
            (pose.x_m * self.inv_xy).floor() as i32,
            (pose.y_m * self.inv_xy).floor() as i32,
            (wrap_angle(pose.yaw_rad) * self.inv_yaw).floor() as i32,
        );
        self.occupied.insert(key);
        self.occupied.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bound_grows_with_bins_and_shrinks_with_error() {
        assert_eq!(kld_bound(1, 0.01, 2.33), 1);
        let b = |k| kld_bound(k, 0.05, 2.33);
        assert!(b(2) < b(10) && b(10) < b(100));
        assert!(kld_bound(50, 0.01, 2.33) > kld_bound(50, 0.05, 2.33));
        // Fox's table: 1000 bins, epsilon 0.05, 99 % need about 1.1e4 samples.
        let n = kld_bound(1000, 0.05, 2.33) as f64;
        assert!((10_000.0..12_500.0).contains(&n), "{n}");
    }

    #[test]
    fn bins_count_distinct_cells() {
        let mut bins = KldBins::new(0.5, 10f64.to_radians());
        assert_eq!(bins.add(&Pose2::new(0.1, 0.1, 0.0)), 1);
        assert_eq!(bins.add(&Pose2::new(0.2, 0.3, 0.01)), 1);
        assert_eq!(bins.add(&Pose2::new(0.6, 0.3, 0.01)), 2);
        assert_eq!(bins.add(&Pose2::new(0.2, 0.3, 0.5)), 3);
        bins.clear();
        assert_eq!(bins.add(&Pose2::new(0.2, 0.3, 0.5)), 1);
    }
}
