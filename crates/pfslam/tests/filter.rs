//! Particle filter: resampling invariants, determinism across thread counts, correlation.

use pfslam::filter::ParticleFilter;
use pfslam::filter::resample::{ResampleMethod, resample};
use pfslam::geometry::Pose2;
use proptest::prelude::*;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;

fn weights_strategy() -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(prop_oneof![Just(0.0), 0.0f64..10.0], 1..200)
        .prop_filter("positive sum", |w| w.iter().sum::<f64>() > 1e-9)
}

fn counts(indices: &[usize], n: usize) -> Vec<usize> {
    let mut c = vec![0; n];
    for &i in indices {
        c[i] += 1;
    }
    c
}

proptest! {
    #[test]
    fn resampling_invariants(w in weights_strategy(), seed in any::<u64>()) {
        let n = w.len();
        let total: f64 = w.iter().sum();
        for method in ResampleMethod::ALL {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
            let mut out = Vec::new();
            resample(&w, method, &mut rng, &mut out);
            prop_assert_eq!(out.len(), n);
            prop_assert!(out.windows(2).all(|p| p[0] <= p[1]), "ancestors sorted");
            let c = counts(&out, n);
            for i in 0..n {
                if w[i] == 0.0 {
                    prop_assert_eq!(c[i], 0, "zero weight chosen ({:?})", method);
                }
                let expected = w[i] / total * n as f64;
                match method {
                    // One position per stratum of width total/n: at most one extra or one
                    // missing beyond floor/ceil of the expectation.
                    ResampleMethod::Systematic => prop_assert!(
                        (c[i] as f64) >= (expected - 1e-9).floor()
                            && (c[i] as f64) <= (expected + 1e-9).ceil(),
                        "systematic count {} vs {}", c[i], expected
                    ),
                    ResampleMethod::Stratified => prop_assert!(
                        (c[i] as f64 - expected).abs() < 2.0 + 1e-9,
                        "stratified count {} vs {}", c[i], expected
                    ),
                    ResampleMethod::Multinomial => {}
                }
            }
            // Determinism: same seed, same draw.
            let mut rng2 = Xoshiro256PlusPlus::seed_from_u64(seed);
            let mut out2 = Vec::new();
            resample(&w, method, &mut rng2, &mut out2);
            prop_assert_eq!(out, out2);
        }
    }

    #[test]
    fn resample_resets_weights(w in weights_strategy(), seed in any::<u64>()) {
        let n = w.len();
        let total: f64 = w.iter().sum();
        let mut pf = ParticleFilter::new(n, Pose2::IDENTITY, seed);
        for (i, p) in pf.particles.poses.iter_mut().enumerate() {
            p.x_m = i as f64;
        }
        pf.particles.weights = w.iter().map(|x| x / total).collect();
        let before = pf.particles.poses.clone();
        let ancestors = pf
            .resample_if_needed(1.0 + 1e-12, ResampleMethod::Stratified)
            .map(<[usize]>::to_vec);
        let ancestors = ancestors.expect("threshold above 1 always resamples");
        prop_assert_eq!(pf.particles.len(), n);
        for (p, &a) in pf.particles.poses.iter().zip(&ancestors) {
            prop_assert_eq!(*p, before[a]);
        }
        prop_assert!(pf.particles.weights.iter().all(|x| (*x - 1.0 / n as f64).abs() < 1e-15));
    }
}

#[test]
fn systematic_counts_are_floor_or_ceil() {
    let w = [0.05, 0.3, 0.0, 0.15, 0.5];
    let n = w.len();
    for seed in 0..200 {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut out = Vec::new();
        resample(&w, ResampleMethod::Systematic, &mut rng, &mut out);
        let c = counts(&out, n);
        for i in 0..n {
            let e = w[i] * n as f64;
            assert!(c[i] as f64 >= e.floor() && c[i] as f64 <= e.ceil(), "{c:?}");
        }
    }
}

#[test]
fn multinomial_frequencies_follow_weights() {
    let w = vec![0.1, 0.2, 0.3, 0.4];
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let mut totals = [0usize; 4];
    let mut out = Vec::new();
    for _ in 0..2000 {
        resample(&w, ResampleMethod::Multinomial, &mut rng, &mut out);
        for (t, c) in totals.iter_mut().zip(counts(&out, 4)) {
            *t += c;
        }
    }
    for (t, wi) in totals.iter().zip(&w) {
        let f = *t as f64 / 8000.0;
        assert!((f - wi).abs() < 0.02, "{f} vs {wi}");
    }
}

/// Prediction with noise in parallel gives the same particles with 1 and 4 threads.
#[test]
fn prediction_is_thread_count_independent() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut pf = ParticleFilter::new(100, Pose2::IDENTITY, 42);
            let noise = Normal::new(0.0, 0.1).unwrap();
            for _ in 0..50 {
                pf.predict(|p, rng| {
                    let d = Pose2::new(0.5 + noise.sample(rng), noise.sample(rng), 0.01);
                    *p = p.compose(&d);
                });
                pf.particles.weights = pf
                    .particles
                    .poses
                    .iter()
                    .map(|p| (-p.y_m * p.y_m).exp())
                    .collect();
                let s: f64 = pf.particles.weights.iter().sum();
                pf.particles.weights.iter_mut().for_each(|w| *w /= s);
                pf.resample_if_needed(0.5, ResampleMethod::Systematic);
            }
            pf.particles
        })
    };
    let a = run(1);
    let b = run(4);
    assert_eq!(a, b);
    // The noise did something.
    assert!(a.poses.iter().any(|p| p.y_m != a.poses[0].y_m));
}
