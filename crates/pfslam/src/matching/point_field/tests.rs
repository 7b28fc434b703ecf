//! The matcher's bit-for-bit tests: the fast paths against plain oracles, and the searches
//! against exhaustive ones.

use super::cells::PointCells;
use super::*;
use crate::geometry::{Pose2, wrap_angle};

fn room_points() -> Vec<[f64; 2]> {
    // An L-shaped room with a pillar: walls every 2 cm.
    let mut pts = Vec::new();
    for k in 0..=400 {
        let t = f64::from(k) * 0.02;
        pts.push([t - 4.0, -3.0]);
        pts.push([t - 4.0, 3.0]);
        if t <= 6.0 {
            pts.push([-4.0, t - 3.0]);
            pts.push([4.0, t - 3.0]);
        }
    }
    for k in 0..60 {
        let a = f64::from(k) * std::f64::consts::TAU / 60.0;
        pts.push([1.5 + 0.3 * a.cos(), 1.0 + 0.3 * a.sin()]);
    }
    pts
}

/// Every 7th of `pts` in the body frame of a robot at `truth`.
fn seen_from(pts: &[[f64; 2]], truth: &Pose2) -> Vec<[f64; 2]> {
    pts.iter()
        .step_by(7)
        .map(|p| {
            let q = truth.inverse().transform_point(p[0], p[1]);
            [q.0, q.1]
        })
        .collect()
}

/// The interpolated score written plainly (libm floor, bounds-checked lookups).
fn score_plain(f: &PointField, points_body: &[[f64; 2]], pose: &Pose2) -> f64 {
    let (s, c) = pose.yaw_rad.sin_cos();
    let sum: f64 = points_body
        .iter()
        .map(|p| {
            let x = pose.x_m + c * p[0] - s * p[1];
            let y = pose.y_m + s * p[0] + c * p[1];
            let u = (x - f.origin_x_m) / f.resolution_m - 0.5;
            let v = (y - f.origin_y_m) / f.resolution_m - 0.5;
            let (fu, fv) = (u.floor(), v.floor());
            let (au, av) = (u - fu, v - fv);
            let (i, j) = (fu as i64, fv as i64);
            let g = |di, dj| f64::from(f.at(0, i + di, j + dj));
            let bottom = g(0, 0) * (1.0 - au) + g(1, 0) * au;
            let top = g(0, 1) * (1.0 - au) + g(1, 1) * au;
            bottom * (1.0 - av) + top * av
        })
        .sum();
    sum / points_body.len() as f64
}

#[test]
fn fast_score_and_shared_bnb_start_give_the_plain_bits() {
    let pts = room_points();
    let f = PointField::build(&pts, [-6.0, -5.0], [6.0, 5.0], 0.05, 0.08, 3);
    let body: Vec<[f64; 2]> = pts.iter().step_by(5).copied().collect();
    for k in 0..200 {
        let t = f64::from(k);
        // Poses that push points across the field's edges (outside cells count 0).
        let pose = Pose2::new((t * 0.37).sin() * 3.0, (t * 0.23).cos() * 2.5, t * 0.05);
        // Every remainder of the four-point batches.
        let part = &body[..body.len() - k as usize % 4];
        let (fast, plain) = (f.score(part, &pose), score_plain(&f, part, &pose));
        assert_eq!(fast.to_bits(), plain.to_bits(), "{pose:?}");
    }
    for v in [
        -3.5, -3.0, -0.0, 0.0, 1e-300, -1e-300, 2.999_999, 1e12, -1e12,
    ] {
        assert_eq!(floor_to_i64(v), v.floor() as i64, "{v}");
    }
    let win = SearchWindow {
        xy_m: 0.4,
        yaw_rad: 0.1,
        yaw_step_rad: 0.02,
    };
    let centre = Pose2::new(0.1, -0.1, 0.03);
    let start = f.bnb_start(&body, &centre, &win).unwrap();
    for (min, ex) in [(0.0, None), (0.3, Some((centre, 0.2, 0.05)))] {
        let a = f.search_bnb(&body, &centre, &win, min, ex);
        let b = f.search_bnb_from(&start, min, ex);
        assert_eq!(a, b);
        assert!(a.is_some());
    }
    // The early-exit existence test answers as the full search does, on both sides of
    // the best score, with and without exclusions.
    let (_, top) = f.search_bnb_from(&start, 0.0, None).unwrap();
    for ratio in [0.0, 0.5, 0.8, 0.9, 0.95, 0.99, 1.0, 1.01] {
        for ex in [
            None,
            Some((centre, 0.05, 0.01)),
            Some((centre, 0.2, 0.05)),
            Some((centre, 1.0, 1.0)),
        ] {
            let full = f.search_bnb_from(&start, ratio * top, ex).is_some();
            assert_eq!(
                f.any_bnb_from(&start, ratio * top, ex),
                full,
                "{ratio} {ex:?}"
            );
        }
    }
}

/// Level `level` of `f` as a dense row-major `w x h` grid.
fn dense(f: &PointField, level: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(f.w * f.h);
    for j in 0..f.h as i64 {
        for i in 0..f.w as i64 {
            out.push(f.at(level, i, j));
        }
    }
    out
}

#[test]
fn banded_build_equals_the_plain_splat() {
    let mut pts: Vec<[f64; 2]> = room_points().iter().step_by(3).copied().collect();
    // Points repeated (a submap's overlapping scans), mostly in the same cells, in
    // another order.
    let again: Vec<[f64; 2]> = pts
        .iter()
        .rev()
        .map(|p| [p[0] + 0.004, p[1] - 0.003])
        .collect();
    pts.extend(again);
    let cases = [
        ([-6.0, -5.0], [6.0, 5.0], 3),
        ([-1.3, -4.1], [2.2, 0.4], 1),
        ([3.9, -3.2], [4.4, 9.0], 0),
        // Mostly empty windows: many tiles absent, the pooled reach across tiles.
        ([-12.0, -9.0], [5.0, 4.0], 4),
        ([-3.0, -20.0], [14.0, 3.5], 6),
    ];
    // Twice, the second time in reverse: every field but the first reuses buffers of
    // other shapes from the pool.
    for &(min, max, levels) in cases.iter().chain(cases.iter().rev()) {
        let (res, sigma) = (0.05, 0.07);
        let f = PointField::build(&pts, min, max, res, sigma, levels);
        // Plain: every point splats the truncated Gaussian, cells keep the maximum.
        let sc: f64 = sigma / res;
        let r = (3.0 * sc).ceil() as i64;
        let mut plain = vec![0f32; f.w * f.h];
        for p in &pts {
            let ci = ((p[0] - min[0]) / res).floor() as i64;
            let cj = ((p[1] - min[1]) / res).floor() as i64;
            for dj in -r..=r {
                for di in -r..=r {
                    let v = (-0.5 * (di * di + dj * dj) as f64 / (sc * sc)).exp() as f32;
                    let (x, y) = (ci + di, cj + dj);
                    let inside = x >= 0 && y >= 0 && x < f.w as i64 && y < f.h as i64;
                    if v > 0.01 && inside {
                        let slot = &mut plain[y as usize * f.w + x as usize];
                        *slot = slot.max(v);
                    }
                }
            }
        }
        assert!(plain.iter().any(|&v| v > 0.5));
        assert_eq!(dense(&f, 0), plain);
        for k in 1..=levels {
            let s = 1usize << k;
            let got = dense(&f, k);
            for y in 0..f.h {
                for x in 0..f.w {
                    let mut m = 0f32;
                    for yy in y..(y + s).min(f.h) {
                        for xx in x..(x + s).min(f.w) {
                            m = m.max(plain[yy * f.w + xx]);
                        }
                    }
                    assert_eq!(got[y * f.w + x], m, "level {k} ({x}, {y})");
                }
            }
        }
    }
}

/// The refinement without batched scores (the oracle): the sequential pattern search,
/// one plain score at a time.
fn refine_sequential(
    f: &PointField,
    points_body: &[[f64; 2]],
    start: &Pose2,
    yaw_step_rad: f64,
    levels: u32,
    prior: Option<&Prior>,
) -> (Pose2, f64) {
    let n_pts = points_body.len().max(1) as f64;
    let objective = |p: &Pose2| {
        let s = score_plain(f, points_body, p);
        (s * n_pts - prior.map_or(0.0, |q| q.penalty(p)), s)
    };
    let ([x_m, y_m, yaw_rad], (_, score)) =
        crate::matching::likelihood_field::pattern_search_sequential(
            [start.x_m, start.y_m, start.yaw_rad],
            objective(start),
            0.5 * f.resolution_m,
            0.5 * yaw_step_rad,
            levels,
            100,
            |at, _| objective(&Pose2::new(at[0], at[1], at[2])),
        );
    (Pose2::new(x_m, y_m, yaw_rad), score)
}

/// The batched scores (1..=6 poses per pass, and more over several passes) equal each
/// pose's plain score, and `refine` (an iteration's candidates scored in one pass)
/// returns the bits of the sequential refinement.
#[test]
fn batched_scores_and_refine_give_the_sequential_bits() {
    let pts = room_points();
    let f = PointField::build(&pts, [-6.0, -5.0], [6.0, 5.0], 0.05, 0.08, 3);
    let body: Vec<[f64; 2]> = pts.iter().step_by(5).copied().collect();
    for k in 0..160usize {
        let t = k as f64;
        // Poses that push points across the field's edges (outside cells count 0),
        // some sharing a yaw as the x/y moves do.
        let poses: Vec<Pose2> = (0..1 + k % 9)
            .map(|i| {
                let u = t + i as f64;
                let yaw = if i % 3 == 0 { t * 0.05 } else { u * 0.05 };
                Pose2::new((u * 0.37).sin() * 3.0, (u * 0.23).cos() * 2.5, yaw)
            })
            .collect();
        let sc: Vec<(f64, f64)> = poses.iter().map(|p| p.yaw_rad.sin_cos()).collect();
        // Every remainder of the four-point batches; some with points beyond the i32
        // range of cells (~1.1e8 m at 0.05 m), whose vector conversion gives i32::MIN.
        let mut far = body.clone();
        if k % 5 == 0 {
            far[k % 7] = [2e8, -1.0];
            far[3 + k % 11] = [2.0, -3e8];
        }
        let part = &far[..far.len() - k % 4];
        let mut got = vec![0.0; poses.len()];
        f.scores_batched(part, &poses, &sc, &mut got);
        for (p, g) in poses.iter().zip(&got) {
            let plain = score_plain(&f, part, p);
            assert_eq!(g.to_bits(), plain.to_bits(), "{k} {p:?}");
            // The portable kernel too (the batch above takes AVX2 where the CPU has it).
            let [portable] = crate::kernels::field_score::portable(
                &f.level(0),
                part,
                [*p],
                [p.yaw_rad.sin_cos()],
            );
            assert_eq!(portable.to_bits(), plain.to_bits(), "{k} {p:?} portable");
        }
    }
    for k in 0..40u32 {
        let t = f64::from(k);
        let start = Pose2::new(
            0.1 * (t * 0.7).sin(),
            0.1 * (t * 1.3).cos(),
            0.04 * (t * 0.9).sin(),
        );
        let prior = Prior {
            pose: Pose2::new(0.02, -0.01, 0.01),
            sigma_xy_m: 0.05 + 0.1 * t,
            sigma_yaw_rad: 0.02,
        };
        let prior = (k % 2 == 0).then_some(&prior);
        let (yaw_step, levels) = (0.01 + 0.001 * t, k % 5);
        let got = f.refine(&body, &start, yaw_step, levels, prior);
        let want = refine_sequential(&f, &body, &start, yaw_step, levels, prior);
        assert_eq!(got.0.x_m.to_bits(), want.0.x_m.to_bits(), "{k}");
        assert_eq!(got.0.y_m.to_bits(), want.0.y_m.to_bits(), "{k}");
        assert_eq!(got.0.yaw_rad.to_bits(), want.0.yaw_rad.to_bits(), "{k}");
        assert_eq!(got.1.to_bits(), want.1.to_bits(), "{k}");
    }
}

/// A window that cuts the scan (its points partly left of and below the field, as a
/// loop candidate's field clipped to its submap leaves the scan's far points): the branch
/// and bound still finds the exhaustive maximum for any number of pooled levels. A
/// pooled cell left of or below the window covers window cells; counting it as 0 (before)
/// made the bound too low and pruned the best pose with 4 or more levels.
#[test]
fn bnb_is_exact_where_the_scan_leaves_the_window() {
    let pts = room_points();
    let truth = Pose2::new(0.3, -0.2, 0.1);
    let body = seen_from(&pts, &truth);
    let win = SearchWindow {
        xy_m: 0.6,
        yaw_rad: 0.06,
        yaw_step_rad: 0.02,
    };
    let centre = Pose2::new(0.05, 0.1, 0.08);
    // The left wall (x = -4) and the bottom wall (y = -3) lie just outside.
    let (lo, hi) = ([-3.93, -2.91], [6.0, 5.0]);
    let n = (win.xy_m / 0.05f64).ceil() as i64;
    for levels in 0..=6 {
        let f = PointField::build(&pts, lo, hi, 0.05, 0.08, levels);
        let mut best = f64::NEG_INFINITY;
        for yaw in PointField::window_yaws(&centre, &win) {
            let cells = f.cells_at(&body, &centre, yaw);
            assert!(cells.x.iter().zip(&cells.y).any(|(&i, &j)| i < 0 || j < 0));
            for dy in -n..=n {
                for dx in -n..=n {
                    best = best.max(f.cell_sum(&cells, 0, dx, dy) / body.len() as f64);
                }
            }
        }
        let (_, score) = f.search_bnb(&body, &centre, &win, 0.0, None).unwrap();
        assert_eq!(score.to_bits(), best.to_bits(), "{levels} levels");
        let start = f.bnb_start(&body, &centre, &win).unwrap();
        assert!(f.any_bnb_from(&start, 0.999_999 * best, None), "{levels}");
        assert!(!f.any_bnb_from(&start, best, None), "{levels}");
    }
}

/// The eight-lane sum gives the point-order sum's bits: every level, offsets inside,
/// across and far beyond the window, cells far out (clamped) and on every side.
#[test]
fn cell_sum_in_any_order_equals_the_point_order_sum() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
    let pts = room_points();
    let f = PointField::build(&pts, [-5.0, -4.0], [6.0, 5.0], 0.05, 0.08, 4);
    let (w, h) = (f.w as i32, f.h as i32);
    for trial in 0..200 {
        let len = rng.random_range(0..300usize);
        let mut cell = |side: i32| match rng.random_range(0..10) {
            0 => rng.random_range(-(1 << 30)..=(1 << 30)),
            1 => rng.random_range(-40..0),
            _ => rng.random_range(0..side + 40),
        };
        let x: Vec<i32> = (0..len).map(|_| cell(w)).collect();
        let y: Vec<i32> = (0..len).map(|_| cell(h)).collect();
        let cells = PointCells { x, y };
        for level in 0..=f.pooled_levels() {
            for (dx, dy) in [(0, 0), (-3, 7), (25, -40), (-(1 << 21), 5), (3, 1 << 25)] {
                let fast = f.cell_sum(&cells, level, dx, dy);
                let plain = crate::kernels::cell_sum::portable(
                    f.level(level),
                    (&cells.x, &cells.y),
                    level,
                    dx,
                    dy,
                );
                assert_eq!(fast.to_bits(), plain.to_bits(), "{trial} {level} {dx} {dy}");
            }
        }
    }
}

#[test]
fn bnb_equals_exhaustive_on_the_cell_grid() {
    let pts = room_points();
    let f = PointField::build(&pts, [-6.0, -5.0], [6.0, 5.0], 0.05, 0.08, 4);
    let truth = Pose2::new(0.3, -0.2, 0.1);
    let body = seen_from(&pts, &truth);
    let win = SearchWindow {
        xy_m: 0.6,
        yaw_rad: 0.2,
        yaw_step_rad: 0.01,
    };
    let centre = Pose2::new(0.0, 0.0, 0.05);
    let (p, s) = f.search_bnb(&body, &centre, &win, 0.0, None).unwrap();
    // Exhaustive reference with a flat prior.
    let prior = Prior {
        pose: centre,
        sigma_xy_m: 1e9,
        sigma_yaw_rad: 1e9,
    };
    let q = f.search_with_prior(&body, &prior, &win);
    assert!(p.between(&q).translation_norm_m() < 1e-9, "{p:?} {q:?}");
    assert!((p.yaw_rad - q.yaw_rad).abs() < 1e-9);
    assert!(p.between(&truth).translation_norm_m() < 0.06, "{p:?}");
    assert!(s > 0.8, "{s}");
    let (r, rs) = f.refine(&body, &p, 0.01, 5, None);
    // The walls lie on cell boundaries, where the bilinear field is flat between the two
    // cell centres: sub-cell accuracy is about half a cell per axis there.
    assert!(
        r.between(&truth).translation_norm_m() < 0.75 * 0.05,
        "{r:?}"
    );
    assert!(wrap_angle(r.yaw_rad - truth.yaw_rad).abs() < 0.004, "{r:?}");
    assert!(rs >= f.score(&body, &p));
}
