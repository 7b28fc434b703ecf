//! The likelihood field's cache: equal to a fresh build after every flush of the simulated
//! car's scans.

use pfslam::geometry::{Pose2, Trajectory};
use pfslam::map::{Cell, CellRect};
use pfslam::map::{MapOptions, PlanarScan, ScanOptions, ScanProjector};
use pfslam::matching::likelihood_field::LikelihoodField;
use pfslam::matching::likelihood_field::cache::FieldCache;
use pfslam::slam::{BestParticleMap, MapPolicy};
use pfslam_sim::SimOptions;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// The cached field equals a fresh build, bit for bit, after every flush of the simulated
/// car's scans (at jittered true poses, so walls appear and vanish), over windows around
/// the car and elsewhere; also with clamping log-odds (walls come and go in two scans)
/// and after an unlogged change (the cache starts over).
#[test]
fn cached_field_equals_a_fresh_build_after_every_flush() {
    let (out, car) = crate::common::simulated_car(&SimOptions {
        duration_s: 8.0,
        ..SimOptions::default()
    });
    let truth = Trajectory::new(out.ground_truth.clone());
    let scan_opts = ScanOptions::default().for_filter();
    let proj = ScanProjector::new(&car.lidar, &car.body_from_lidar, &scan_opts).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    for (case, clamping) in [(0usize, false), (1, true)] {
        let mut opts = MapOptions::default();
        opts.height.enabled = false;
        if clamping {
            opts.log_odds.hit = 20.0;
            opts.log_odds.miss = -20.0;
            opts.log_odds.clamp_min = -40.0;
            opts.log_odds.clamp_max = 40.0;
        }
        let grid = pfslam::map::OccupancyGrid::new(&opts).unwrap();
        let mut policy = BestParticleMap::new(grid);
        let (mut cached, mut fresh) = (LikelihoodField::new(), LikelihoodField::new());
        let threshold = cached.source_threshold_on(&policy.grid);
        policy.log_changes(threshold);
        let mut cache = FieldCache::new();
        let mut body = PlanarScan::default();
        let (mut flushes, mut changed) = (0, 0);
        for k in (100..car.scans.len()).step_by(3) {
            let Some(pose) = truth.pose_at(car.scans.stamps_ns[k]) else {
                continue;
            };
            let pose = Pose2::new(
                pose.x_m + rng.random_range(-0.05..0.05),
                pose.y_m + rng.random_range(-0.05..0.05),
                pose.yaw_rad + rng.random_range(-0.01..0.01),
            );
            proj.to_body(car.scans.ranges(k), &mut body).unwrap();
            policy.integrate_at(&pose, &body).unwrap();
            if k % 5 != 0 {
                continue;
            }
            policy.flush().unwrap();
            flushes += 1;
            if flushes == 20 {
                // A change nobody logged: the cache must start over.
                let c = policy.grid.cell_of(pose.x_m + 3.0, pose.y_m);
                policy.grid.set_fixed(c, 2000).unwrap();
                policy.log_changes(threshold);
            }
            let c = policy.grid.cell_of(pose.x_m, pose.y_m);
            let w = rng.random_range(20..300);
            let rect = CellRect {
                min_i: c.i - w,
                min_j: c.j - rng.random_range(20..300),
                max_i: c.i + rng.random_range(20..300),
                max_j: c.j + w,
            };
            let unknown = [0.5, 1.0][case];
            let reset = flushes == 20;
            policy.take_changes(0, |grid, changes| {
                if let Some(ch) = changes {
                    changed += ch.len();
                }
                let changes = if reset { None } else { changes };
                cached.build_cached(grid, &rect, 0.15, unknown, &mut cache, changes);
                fresh.build(grid, &rect, 0.15, unknown);
            });
            let (mut a, mut b) = (Vec::new(), Vec::new());
            for j in rect.min_j - 2..=rect.max_j + 2 {
                for i in rect.min_i - 2..=rect.max_i + 2 {
                    a.push(cached.at(Cell::new(i, j)));
                    b.push(fresh.at(Cell::new(i, j)));
                }
            }
            assert!(a == b, "case {case}, flush {flushes}: fields differ");
        }
        assert!(
            flushes > 40 && changed > 1000,
            "case {case}: {flushes} flushes, {changed} changes"
        );
    }
}
