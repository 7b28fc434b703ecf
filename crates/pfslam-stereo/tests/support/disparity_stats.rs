//! Disparity accuracy against the exact disparity of a rendered scene: shared by the stereo
//! tests (rendered ground plane) and the simulator's camera tests (rendered worlds).

use pfslam_stereo::{DisparityMap, StereoOptions};

/// The `q`-quantile (0..=1) of sorted values.
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Disparity error against the exact one where the true disparity is within the search range
/// (depth up to ~18 m) and away from the image border.
#[derive(Clone, Copy)]
pub struct DisparityStats {
    candidates: usize,
    /// Fraction of the candidates with a disparity.
    valid: f64,
    /// Median |error| (px).
    median: f64,
    /// 90th percentile |error| (px).
    p90: f64,
    /// Fraction of the valid pixels off by more than 2 px.
    gross: f64,
}

impl DisparityStats {
    /// Prints the figures and asserts the bounds every rendered scene must meet.
    pub fn check(&self, label: &str) {
        let DisparityStats {
            candidates,
            valid,
            median,
            p90,
            gross,
        } = *self;
        eprintln!(
            "{label}: {candidates} pixels, valid {:.1} %, |error| median {median:.3} px, p90 \
             {p90:.3} px, > 2 px {:.2} %",
            100.0 * valid,
            100.0 * gross
        );
        assert!(valid > 0.6, "{label}: valid {valid}");
        assert!(median < 0.3, "{label}: median {median}");
        assert!(p90 < 0.8, "{label}: p90 {p90}");
        assert!(gross < 0.05, "{label}: gross {gross}");
    }

    pub fn measure(truth: &[f32], disparity: &DisparityMap, options: &StereoOptions) -> Self {
        let max_d = (options.matcher.num_disparities - 1) as f32;
        let (mut errors, mut candidates) = (Vec::new(), 0usize);
        for (i, &t) in truth.iter().enumerate() {
            let (u, v) = (i % disparity.width, i / disparity.width);
            if !(t >= 20.0 && t <= max_d - 1.0)
                || u < 20
                || u + 20 > disparity.width
                || v + 12 > disparity.height
            {
                continue;
            }
            candidates += 1;
            if disparity.data[i] >= 0.0 {
                errors.push((disparity.data[i] - t).abs() as f64);
            }
        }
        errors.sort_by(f64::total_cmp);
        DisparityStats {
            candidates,
            valid: errors.len() as f64 / candidates as f64,
            median: percentile(&errors, 0.5),
            p90: percentile(&errors, 0.9),
            gross: errors.iter().filter(|e| **e > 2.0).count() as f64 / errors.len() as f64,
        }
    }
}
