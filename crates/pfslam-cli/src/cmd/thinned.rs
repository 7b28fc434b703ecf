//! Poses kept for a picture in bounded memory, however long the path.

/// At most this many poses are kept: every k-th pose, k doubling as the path grows.
pub const PLOT_POSES_MAX: usize = 1 << 14;

/// Every `step`-th pose pushed, `step` doubling whenever [`PLOT_POSES_MAX`] are kept.
#[derive(Debug, Clone)]
pub struct Thinned<T> {
    /// The poses kept, in order.
    pub poses: Vec<T>,
    step: usize,
    seen: usize,
}

impl<T> Default for Thinned<T> {
    fn default() -> Self {
        Thinned {
            poses: Vec::new(),
            step: 1,
            seen: 0,
        }
    }
}

impl<T: Copy> Thinned<T> {
    /// Keeps `p` when it is a `step`-th pose.
    pub fn push(&mut self, p: T) {
        if self.seen.is_multiple_of(self.step) {
            if self.poses.len() == PLOT_POSES_MAX {
                self.step *= 2;
                let keep: Vec<T> = self.poses.iter().step_by(2).copied().collect();
                self.poses = keep;
            }
            if self.seen.is_multiple_of(self.step) {
                self.poses.push(p);
            }
        }
        self.seen += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_path_keeps_at_most_the_limit_evenly_and_in_order() {
        let mut t = Thinned::default();
        let n = 5 * PLOT_POSES_MAX + 3;
        for i in 0..n {
            t.push(i);
        }
        assert!(t.poses.len() <= PLOT_POSES_MAX && t.poses.len() > PLOT_POSES_MAX / 2);
        assert_eq!(t.poses[0], 0);
        let step = t.poses[1] - t.poses[0];
        assert!(t.poses.windows(2).all(|w| w[1] - w[0] == step), "uneven");
        assert!(n - t.poses[t.poses.len() - 1] <= step);
    }
}
