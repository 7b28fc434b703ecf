//! Weight updates in log space and the effective sample size.

/// Effective sample size `1 / sum(w^2)` of normalised weights (0 for an empty set).
pub fn neff(weights: &[f64]) -> f64 {
    let s: f64 = weights.iter().map(|w| w * w).sum();
    if s > 0.0 { 1.0 / s } else { 0.0 }
}

/// Multiplies normalised `weights` by `exp(score / temperature)` and renormalises, in log
/// space with the maximum subtracted so large scores (hundreds of map hits) cannot overflow:
/// `log w_i += score_i / T; w_i = exp(log w_i - max); w /= sum(w)`.
///
/// `temperature` divides the scores (the ESE650 seed uses 10; 1 is the plain softmax of the
/// UCSD seed); it must be positive. Should every weight vanish (impossible for finite inputs,
/// since the maximum maps to 1) the weights are reset to uniform rather than becoming NaN.
pub fn update_log_space(weights: &mut [f64], scores: &[f64], temperature: f64) {
    debug_assert_eq!(weights.len(), scores.len());
    let n = weights.len();
    if n == 0 {
        return;
    }
    let inv_t = 1.0 / temperature;
    let mut max = f64::NEG_INFINITY;
    for (w, s) in weights.iter_mut().zip(scores) {
        // ln(0) = -inf keeps a dead particle dead.
        *w = w.ln() + s * inv_t;
        if *w > max {
            max = *w;
        }
    }
    let mut sum = 0.0;
    for w in weights.iter_mut() {
        *w = (*w - max).exp();
        sum += *w;
    }
    if !(sum.is_finite() && sum > 0.0) {
        weights.fill(1.0 / n as f64);
        return;
    }
    let inv = 1.0 / sum;
    for w in weights.iter_mut() {
        *w *= inv;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn softmax_of_large_scores_is_stable() {
        let mut w = vec![0.25; 4];
        update_log_space(&mut w, &[1000.0, 1001.0, 999.0, 1000.0], 1.0);
        let s: f64 = w.iter().sum();
        assert!((s - 1.0).abs() < 1e-12);
        let e = 1f64.exp();
        let z = 2.0 + e + 1.0 / e;
        assert!((w[1] - e / z).abs() < 1e-12);
        assert!((w[0] - 1.0 / z).abs() < 1e-12);
    }

    #[test]
    fn temperature_flattens() {
        let mut a = vec![0.5, 0.5];
        let mut b = a.clone();
        update_log_space(&mut a, &[0.0, 10.0], 1.0);
        update_log_space(&mut b, &[0.0, 10.0], 10.0);
        assert!(b[0] > a[0]);
        assert!((b[1] / b[0] - 1f64.exp()).abs() < 1e-9);
    }

    #[test]
    fn prior_weights_multiply() {
        let mut w = vec![0.2, 0.8];
        update_log_space(&mut w, &[0.0, 0.0], 1.0);
        assert!((w[0] - 0.2).abs() < 1e-12);
        let mut w = vec![0.0, 1.0];
        update_log_space(&mut w, &[100.0, 0.0], 1.0);
        assert_eq!(w, vec![0.0, 1.0]);
    }

    #[test]
    fn neff_bounds() {
        assert!((neff(&[0.25; 4]) - 4.0).abs() < 1e-12);
        assert!((neff(&[1.0, 0.0, 0.0]) - 1.0).abs() < 1e-12);
        assert_eq!(neff(&[]), 0.0);
    }
}
