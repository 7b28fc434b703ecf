use super::*;
use crate::geometry::{Pose2, StampedPose2, wrap_angle};
use crate::map::{Cell, InsertScratch, OccupancyGrid, PlanarScan};
use crate::matching::nearest_occupied::*;
use rand::RngExt;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::sync::Arc;

fn node(pose: Pose2, odom: Pose2, scan: usize, parent: &Arc<PathNode>) -> Arc<PathNode> {
    Arc::new(PathNode {
        pose,
        odom,
        scan,
        parent: Some(parent.clone()),
    })
}

/// A 5 cm grid after one scan from the origin with a return at each of `points`.
fn grid_seeing(points: &[[f64; 2]]) -> OccupancyGrid {
    use crate::map::MapOptions;
    let mut grid = OccupancyGrid::new(&MapOptions {
        resolution_m: 0.05,
        ..MapOptions::default()
    })
    .unwrap();
    let scan = PlanarScan::hits_from_origin(points);
    grid.insert_scan(&scan, &mut InsertScratch::new()).unwrap();
    grid
}

#[test]
fn output_path_is_the_survivors_history_with_odometry_between_nodes() {
    let o = |x: f64| Pose2::new(x, 0.0, 0.0);
    let root = Arc::new(PathNode {
        pose: o(0.0),
        odom: o(0.0),
        scan: 0,
        parent: None,
    });
    // Two particles branch at scan 2: A thinks it is at y = +1, B at y = -1.
    let a = node(Pose2::new(2.0, 1.0, 0.0), o(2.0), 2, &root);
    let b = node(Pose2::new(2.0, -1.0, 0.0), o(2.0), 2, &root);
    // Resampling keeps only B (two copies); they extend B's history.
    let b1 = node(Pose2::new(4.0, -1.0, 0.0), o(4.0), 4, &b);
    let b2 = node(Pose2::new(4.0, -1.2, 0.0), o(4.0), 4, &b);
    drop(a);
    let odometry: Vec<StampedPose2> = (0..6)
        .map(|k| StampedPose2 {
            stamp_ns: k as i64,
            pose: o(k as f64),
        })
        .collect();
    let path = path_poses(&b2, &odometry);
    let ys: Vec<f64> = path.iter().map(|p| p.pose.y_m).collect();
    let xs: Vec<f64> = path.iter().map(|p| p.pose.x_m).collect();
    assert_eq!(ys, vec![0.0, 0.0, -1.0, -1.0, -1.2, -1.2]);
    assert_eq!(xs, vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
    assert_eq!(path_poses(&b1, &odometry)[5].pose.y_m, -1.0);
    assert_eq!(ancestry(&b2).len(), 3);
}

#[test]
fn dropping_a_long_path_does_not_recurse() {
    let mut leaf = Arc::new(PathNode {
        pose: Pose2::IDENTITY,
        odom: Pose2::IDENTITY,
        scan: 0,
        parent: None,
    });
    for k in 1..1_000_000 {
        leaf = node(Pose2::IDENTITY, Pose2::IDENTITY, k, &leaf);
    }
    drop(leaf);
}

/// The observation model written plainly (the kernel before it was optimised).
fn scan_log_likelihood_plain(
    grid: &OccupancyGrid,
    model: &ObservationModel,
    points: &[[f64; 2]],
    pose: &Pose2,
) -> f64 {
    let (s, c) = pose.yaw_rad.sin_cos();
    let k = model.kernel;
    let mut total = 0.0;
    for p in points {
        let x = pose.x_m + c * p[0] - s * p[1];
        let y = pose.y_m + s * p[0] + c * p[1];
        let (u, v) = grid.limits().cell_coords(x, y);
        let (i, j) = (u.floor() as i32, v.floor() as i32);
        let mut best = f64::INFINITY;
        for dj in -k..=k {
            let dv = v - (f64::from(j + dj) + 0.5);
            for di in -k..=k {
                if grid.logodds_fixed(Cell::new(i + di, j + dj)) > model.occupied_fixed {
                    let du = u - (f64::from(i + di) + 0.5);
                    best = best.min(du * du + dv * dv);
                }
            }
        }
        total += if best.is_finite() {
            (-best * model.res2_over_2s2).max(model.no_hit)
        } else {
            model.no_hit
        };
    }
    total
}

#[test]
fn optimised_likelihood_equals_the_plain_rule_bit_for_bit() {
    use crate::map::{MapOptions, ScanPoint};
    use rand::SeedableRng;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    let mut uni = |a: f64, b: f64| a + (b - a) * rng.random::<f64>();
    for trial in 0..12 {
        let res = [0.05, 0.1, 0.03][trial % 3];
        let mut grid = OccupancyGrid::new(&MapOptions {
            resolution_m: res,
            ..MapOptions::default()
        })
        .unwrap();
        // Random walls seen from a few poses: occupied, free and unwritten cells, tile
        // borders crossed everywhere.
        let mut scratch = InsertScratch::new();
        for _ in 0..4 {
            let (sx, sy) = (uni(-2.0, 2.0), uni(-2.0, 2.0));
            let points = (0..120)
                .map(|_| {
                    let (a, r) = (uni(-3.2, 3.2), uni(0.5, 6.0));
                    ScanPoint {
                        x_m: sx + r * a.cos(),
                        y_m: sy + r * a.sin(),
                        hit: uni(0.0, 1.0) < 0.9,
                        free_to: 1.0,
                        z_m: 0.0,
                    }
                })
                .collect();
            let scan = PlanarScan {
                sensor_x_m: sx,
                sensor_y_m: sy,
                sensor_z_m: None,
                points,
            };
            grid.insert_scan(&scan, &mut scratch).unwrap();
        }
        let mut body: Vec<[f64; 2]> = (0..200).map(|_| [uni(-7.0, 7.0), uni(-7.0, 7.0)]).collect();
        // Points ~5e7 m out: beyond 2^30 cells at 0.03 m, where the chunks holding them
        // take the scalar floor (the vector floor's range ends there), and inside the i32
        // range at every resolution here (so `i + di` cannot overflow).
        for (at, far) in [(37, [5e7, 1.0]), (38, [-2.0, -5e7]), (121, [-3.5e7, 3.5e7])] {
            body.insert(at, far);
        }
        for kernel in [0, 1, 2] {
            for occupied_logodds in [0.0, -0.5, 0.7] {
                let o = RbpfOptions {
                    likelihood: RbpfLikelihood {
                        kernel_cells: kernel,
                        occupied_logodds,
                        ..RbpfLikelihood::default()
                    },
                    ..RbpfOptions::default()
                };
                let model = o.observation(res);
                for _ in 0..10 {
                    let pose = Pose2::new(uni(-1.0, 1.0), uni(-1.0, 1.0), uni(-3.2, 3.2));
                    let fast = scan_log_likelihood(&grid, &model, &body, &pose);
                    let plain = scan_log_likelihood_plain(&grid, &model, &body, &pose);
                    assert_eq!(fast.to_bits(), plain.to_bits(), "{trial} {kernel} {pose:?}");
                    // The path taken without AVX2, whatever this machine has.
                    let scalar =
                        crate::kernels::likelihood::portable(&grid, &model, &body, &pose, None);
                    assert_eq!(
                        scalar.to_bits(),
                        plain.to_bits(),
                        "{trial} {kernel} {pose:?}"
                    );
                }
            }
        }
    }
}

/// The matcher without the early stop and the memo of evaluated poses: every candidate
/// fully evaluated, only the pose just left skipped, the weight recomputed.
fn match_in_own_map_plain(
    grid: &OccupancyGrid,
    model: &ObservationModel,
    points: &[[f64; 2]],
    start: &Pose2,
    search: &SearchParams,
) -> (Pose2, f64) {
    let prior = search.prior;
    let eval = |p: &Pose2| {
        let ll = scan_log_likelihood_plain(grid, model, points, p);
        match prior {
            Some(pr) => {
                let (dx, dy) = (p.x_m - start.x_m, p.y_m - start.y_m);
                let da = wrap_angle(p.yaw_rad - start.yaw_rad);
                ll - 0.5 * ((dx * dx + dy * dy) * pr.inv_var_xy + da * da * pr.inv_var_yaw)
            }
            None => ll,
        }
    };
    let mut best = *start;
    let mut best_ll = eval(&best);
    let r = search.xy_cells;
    for &dyaw in &search.yaw_offsets_rad {
        for oy in -r..=r {
            for ox in -r..=r {
                if dyaw == 0.0 && ox == 0 && oy == 0 {
                    continue;
                }
                let cand = Pose2::new(
                    start.x_m + f64::from(ox) * search.resolution_m,
                    start.y_m + f64::from(oy) * search.resolution_m,
                    start.yaw_rad + dyaw,
                );
                let ll = eval(&cand);
                if ll > best_ll {
                    best_ll = ll;
                    best = cand;
                }
            }
        }
    }
    let (mut sxy, mut syaw) = (search.step_xy_m, search.step_yaw_rad);
    let (mut level, mut iterations) = (0, 0);
    while level < search.refine_levels && iterations < 200 {
        iterations += 1;
        let mut moved: Option<(Pose2, f64)> = None;
        for (ex, ey, ea) in [
            (sxy, 0.0, 0.0),
            (-sxy, 0.0, 0.0),
            (0.0, sxy, 0.0),
            (0.0, -sxy, 0.0),
            (0.0, 0.0, syaw),
            (0.0, 0.0, -syaw),
        ] {
            let cand = Pose2::new(best.x_m + ex, best.y_m + ey, best.yaw_rad + ea);
            let ll = eval(&cand);
            if ll > moved.map_or(best_ll, |m| m.1) {
                moved = Some((cand, ll));
            }
        }
        match moved {
            Some((p, ll)) => {
                best = p;
                best_ll = ll;
            }
            None => {
                sxy *= 0.5;
                syaw *= 0.5;
                level += 1;
            }
        }
    }
    best.yaw_rad = wrap_angle(best.yaw_rad);
    let ll = if prior.is_some() {
        scan_log_likelihood_plain(grid, model, points, &best)
    } else {
        best_ll
    };
    (best, ll)
}

#[test]
fn matcher_with_early_stops_equals_the_plain_climb_bit_for_bit() {
    use rand::SeedableRng;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let mut uni = |a: f64, b: f64| a + (b - a) * rng.random::<f64>();
    // Walls of a room and a few posts, seen from its middle.
    let mut wall: Vec<[f64; 2]> = Vec::new();
    for k in 0..160 {
        let t = f64::from(k) * 0.05 - 4.0;
        wall.extend([[t, 3.0], [t, -2.5], [4.0, 0.7 * t], [-4.0, 0.6 * t]]);
    }
    for k in 0..24 {
        let a = f64::from(k) * 15f64.to_radians();
        wall.extend([
            [1.0 + 0.2 * a.cos(), 1.0 + 0.2 * a.sin()],
            [-2.0 + 0.3 * a.cos(), -1.0 + 0.15 * a.sin()],
        ]);
    }
    let grid = grid_seeing(&wall);
    let body: Vec<[f64; 2]> = wall.iter().step_by(3).copied().collect();
    let o = RbpfOptions::default();
    let model = o.observation(0.05);
    let mut checked = 0;
    for trial in 0..60 {
        let mut search = o.search_params(0.05);
        search.xy_cells = (trial % 3) / 2;
        search.prior = (trial % 4 != 0).then(|| MatchPrior {
            inv_var_xy: 1.0 / uni(0.01, 0.2).powi(2),
            inv_var_yaw: 1.0 / uni(0.01, 0.1).powi(2),
        });
        // Starts off the truth, some near +-pi (the climb wraps the yaw).
        let yaw = if trial % 5 == 0 {
            std::f64::consts::PI - uni(0.0, 0.03)
        } else {
            uni(-0.08, 0.08)
        };
        let start = Pose2::new(uni(-0.15, 0.15), uni(-0.15, 0.15), yaw);
        let (fast, ll) = match_in_own_map(&grid, &model, &body, &start, &search);
        let (plain, plain_ll) = match_in_own_map_plain(&grid, &model, &body, &start, &search);
        let b = |p: &Pose2| [p.x_m, p.y_m, p.yaw_rad].map(f64::to_bits);
        assert_eq!(b(&fast), b(&plain), "{trial} {start:?}");
        assert_eq!(ll.to_bits(), plain_ll.to_bits(), "{trial}");
        checked += usize::from(b(&fast) != b(&start));
    }
    // Most searches moved away from their start.
    assert!(checked > 40, "{checked}");
}

#[test]
fn likelihood_peaks_at_the_true_pose_and_the_matcher_finds_it() {
    // An L-shaped room corner (walls through cell centres) plus a pillar.
    let mut points = Vec::new();
    for k in 0..200 {
        let t = f64::from(k) * 0.05 - 5.0;
        points.push([t, 3.025]);
        points.push([4.025, t]);
    }
    for k in 0..36 {
        let a = f64::from(k) * 10f64.to_radians();
        points.push([1.5 + 0.3 * a.cos(), -1.0 + 0.3 * a.sin()]);
    }
    let grid = grid_seeing(&points);
    let o = RbpfOptions::default();
    let model = o.observation(0.05);
    let search = o.search_params(0.05);
    let at_truth = scan_log_likelihood(&grid, &model, &points, &Pose2::IDENTITY);
    let off = scan_log_likelihood(&grid, &model, &points, &Pose2::new(0.1, 0.0, 0.0));
    assert!(at_truth > off, "{at_truth} {off}");
    for start in [
        Pose2::new(0.04, -0.03, 2f64.to_radians()),
        Pose2::new(-0.05, 0.04, -2.5f64.to_radians()),
    ] {
        let (pose, _) = match_in_own_map(&grid, &model, &points, &start, &search);
        assert!(pose.translation_norm_m() < 0.02, "{pose:?} from {start:?}");
        assert!(pose.yaw_rad.abs() < 0.3f64.to_radians(), "{pose:?}");
    }
}
