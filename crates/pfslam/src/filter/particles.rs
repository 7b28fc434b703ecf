//! The particle set: poses and normalised weights.

use crate::geometry::Pose2;

/// N weighted pose hypotheses. Weights are kept normalised (they sum to 1).
#[derive(Debug, Clone, PartialEq)]
pub struct ParticleSet {
    /// Each particle's `world_from_body` pose.
    pub poses: Vec<Pose2>,
    /// Each particle's normalised weight.
    pub weights: Vec<f64>,
}

impl ParticleSet {
    /// `n` particles at `pose`, each with weight `1/n`.
    pub fn new(n: usize, pose: Pose2) -> Self {
        ParticleSet {
            poses: vec![pose; n],
            weights: vec![1.0 / n.max(1) as f64; n],
        }
    }

    /// Number of particles.
    #[inline]
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when there is no particle.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Index of the heaviest particle (the first one on ties, so the choice is deterministic);
    /// 0 when empty.
    pub fn best_index(&self) -> usize {
        let mut best = 0;
        for (i, w) in self.weights.iter().enumerate() {
            if *w > self.weights[best] {
                best = i;
            }
        }
        best
    }

    /// The effective sample size `1 / sum(w^2)`.
    pub fn neff(&self) -> f64 {
        super::weights::neff(&self.weights)
    }

    /// Replaces the particles by the ancestors `indices` (from a resampler) and resets every
    /// weight to `1/n`. `scratch` is a caller-owned buffer.
    pub fn apply_resample(&mut self, indices: &[usize], scratch: &mut Vec<Pose2>) {
        scratch.clear();
        scratch.extend(indices.iter().map(|&i| self.poses[i]));
        std::mem::swap(&mut self.poses, scratch);
        let n = self.poses.len();
        self.weights.clear();
        self.weights.resize(n, 1.0 / n.max(1) as f64);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn best_index_first_on_ties() {
        let mut p = ParticleSet::new(4, Pose2::IDENTITY);
        assert_eq!(p.best_index(), 0);
        p.weights = vec![0.1, 0.4, 0.4, 0.1];
        assert_eq!(p.best_index(), 1);
    }

    #[test]
    fn apply_resample_resets_weights() {
        let mut p = ParticleSet::new(3, Pose2::IDENTITY);
        p.poses[2].x_m = 5.0;
        p.weights = vec![0.0, 0.0, 1.0];
        let mut scratch = Vec::new();
        p.apply_resample(&[2, 2, 2], &mut scratch);
        assert!(p.poses.iter().all(|q| q.x_m == 5.0));
        assert!(p.weights.iter().all(|w| (*w - 1.0 / 3.0).abs() < 1e-15));
    }
}
