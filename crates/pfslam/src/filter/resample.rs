//! Resampling: draw N ancestors in proportion to the weights.
//!
//! All three schemes walk the cumulative weights once with sorted positions in `[0, total)`,
//! so they are O(N) (multinomial adds a sort) and return ancestors in ascending order.

use rand::{Rng, RngExt};
use serde::{Deserialize, Serialize};

/// How ancestors are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ResampleMethod {
    /// One uniform per stratum `[k/N, (k+1)/N)` (the ESE650 seed's choice).
    #[default]
    Stratified,
    /// One uniform offset shared by all strata: lowest variance, O(N).
    Systematic,
    /// N independent draws.
    Multinomial,
}

impl ResampleMethod {
    /// Every method, for tests and reports.
    pub const ALL: [ResampleMethod; 3] = [
        ResampleMethod::Stratified,
        ResampleMethod::Systematic,
        ResampleMethod::Multinomial,
    ];
}

/// Fills `out` with `weights.len()` ancestor indices drawn by `method`. Weights need not be
/// normalised but must be non-negative with a positive finite sum; otherwise every particle
/// is its own ancestor (identity), which leaves the set unchanged rather than inventing one.
pub fn resample<R: Rng + ?Sized>(
    weights: &[f64],
    method: ResampleMethod,
    rng: &mut R,
    out: &mut Vec<usize>,
) {
    let n = weights.len();
    out.clear();
    if n == 0 {
        return;
    }
    let total: f64 = weights.iter().sum();
    if !(total.is_finite() && total > 0.0) || weights.iter().any(|w| w.is_nan() || *w < 0.0) {
        out.extend(0..n);
        return;
    }
    let step = total / n as f64;
    let mut positions = Vec::with_capacity(n);
    match method {
        ResampleMethod::Stratified => {
            positions.extend((0..n).map(|k| (k as f64 + rng.random::<f64>()) * step));
        }
        ResampleMethod::Systematic => {
            let u: f64 = rng.random();
            positions.extend((0..n).map(|k| (k as f64 + u) * step));
        }
        ResampleMethod::Multinomial => {
            positions.extend((0..n).map(|_| rng.random::<f64>() * total));
            positions.sort_by(f64::total_cmp);
        }
    }
    // Walk the cumulative sum. Skipping zero-weight particles guarantees they are never
    // chosen even when a position lands exactly on a boundary.
    let mut i = 0;
    let mut cumulative = weights[0];
    for p in positions {
        while (p >= cumulative || weights[i] == 0.0) && i + 1 < n {
            i += 1;
            cumulative += weights[i];
        }
        // Rounding can leave the last positions past the final cumulative sum: they belong
        // to the last particle with positive weight.
        let mut j = i;
        while weights[j] == 0.0 && j > 0 {
            j -= 1;
        }
        out.push(j);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    #[test]
    fn uniform_weights_systematic_is_identity() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let mut out = Vec::new();
        resample(&[0.2; 5], ResampleMethod::Systematic, &mut rng, &mut out);
        assert_eq!(out, vec![0, 1, 2, 3, 4]);
    }

    #[test]
    fn degenerate_weights_pick_the_only_particle() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let mut out = Vec::new();
        for m in ResampleMethod::ALL {
            resample(&[0.0, 0.0, 1.0, 0.0], m, &mut rng, &mut out);
            assert_eq!(out, vec![2; 4], "{m:?}");
        }
    }

    #[test]
    fn invalid_weights_give_identity() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let mut out = Vec::new();
        resample(&[0.0, 0.0], ResampleMethod::Stratified, &mut rng, &mut out);
        assert_eq!(out, vec![0, 1]);
        resample(
            &[f64::NAN, 1.0],
            ResampleMethod::Stratified,
            &mut rng,
            &mut out,
        );
        assert_eq!(out, vec![0, 1]);
    }
}
