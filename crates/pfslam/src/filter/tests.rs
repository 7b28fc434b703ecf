use super::*;

/// Odometry composed without noise: the reference of [`ParticleFilter::predict_exact`].
struct ExactOdometry;

impl MotionModel for ExactOdometry {
    fn sample(
        &self,
        pose: &Pose2,
        from: &StampedPose2,
        to: &StampedPose2,
        _rng: &mut Xoshiro256PlusPlus,
    ) -> Pose2 {
        pose.compose(&from.pose.between(&to.pose))
    }
}

#[test]
fn exact_prediction_equals_the_per_particle_odometry_bit_for_bit() {
    use rand::{RngExt, SeedableRng};
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
    let mut odo = |t: i64| StampedPose2 {
        stamp_ns: t,
        pose: Pose2::new(
            rng.random_range(-50.0..50.0),
            rng.random_range(-50.0..50.0),
            rng.random_range(-3.2..3.2),
        ),
    };
    let mut steps = Vec::new();
    let mut prev = odo(0);
    for t in 1..40 {
        let next = odo(t);
        steps.push((prev, next));
        prev = next;
    }
    for n in [1, 7, 100, 300] {
        let mut a = ParticleFilter::new(n, Pose2::new(1.0, -2.0, 0.3), 5);
        a.jitter(0.5, 0.2);
        let mut b = a.clone();
        a.predict_steps(&steps, &ExactOdometry);
        b.predict_exact(&steps, &mut Vec::new());
        for (p, q) in a.particles.poses.iter().zip(&b.particles.poses) {
            assert_eq!(
                [p.x_m, p.y_m, p.yaw_rad].map(f64::to_bits),
                [q.x_m, q.y_m, q.yaw_rad].map(f64::to_bits),
                "{n} particles"
            );
        }
    }
}
