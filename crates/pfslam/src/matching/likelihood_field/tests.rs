use super::*;
use crate::geometry::Pose2;
use crate::kernels::coarse::{CoarseYaw, coarse_sums, coarse_sums_fast, coarse_sums_swar};
use crate::kernels::rotation::Rotation;
use crate::kernels::rotation_f32::{LANES32, RotationF32};
use crate::map::{CellRect, OccupancyGrid};
use crate::map::{MapOptions, PlanarScan, to_world};

/// The search of the scan-matching mode's default options (`[filter.scan_match]`).
fn search() -> MatchSearch {
    MatchSearch {
        xy_radius_cells: 3,
        yaw_search_deg: 0.25,
        yaw_step_deg: 0.25,
        prior_sigma_xy_m: 0.02,
        prior_sigma_yaw_deg: 0.05,
        point_gain: 1.0,
        refine_levels: 3,
    }
}

/// A room with walls at x = +-5 m and y = +-4 m, with a pillar, mapped from the origin.
fn room_scan() -> PlanarScan {
    let mut points = Vec::new();
    for k in 0..720 {
        let a = f64::from(k) * std::f64::consts::PI / 360.0;
        let (s, c) = a.sin_cos();
        // Walls through cell centres (0.1 m cells), so the map has no quantisation offset.
        let tx = if c > 1e-9 {
            5.05 / c
        } else if c < -1e-9 {
            -4.95 / c
        } else {
            f64::MAX
        };
        let ty = if s > 1e-9 {
            4.05 / s
        } else if s < -1e-9 {
            -3.95 / s
        } else {
            f64::MAX
        };
        let mut t = tx.min(ty);
        // pillar: circle radius 0.3 at (2, 1)
        let (px, py) = (2.0, 1.0);
        let b = c * px + s * py;
        let disc = b * b - (px * px + py * py - 0.09);
        if disc >= 0.0 && b - disc.sqrt() > 0.0 {
            t = t.min(b - disc.sqrt());
        }
        points.push([c * t, s * t]);
    }
    PlanarScan::hits_from_origin(&points)
}

#[test]
fn match_recovers_small_offsets_sub_cell() {
    let (field, pts) = room_field(0.0);
    let o = MatchSearch {
        prior_sigma_xy_m: 10.0,
        prior_sigma_yaw_deg: 50.0,
        ..search()
    };
    let mut ms = MatchScratch::default();
    for precision in [KernelPrecision::F64, KernelPrecision::F32] {
        let params = MatchParams {
            kernel_precision: precision,
            ..MatchParams::new(0.1, &o)
        };
        for (dx, dy, dyaw_deg) in [(0.17, -0.12, 0.4), (-0.23, 0.08, -0.6), (0.04, 0.26, 0.0)] {
            let predicted = Pose2::new(dx, dy, f64::to_radians(dyaw_deg));
            let m = match_scan(&field, &pts, &predicted, &params, &mut ms);
            assert!(
                m.pose.translation_norm_m() < 0.03,
                "{precision:?}: {m:?} from {predicted:?}"
            );
            assert!(m.pose.yaw_rad.abs() < 0.15f64.to_radians(), "{m:?}");
            assert!(m.fit > 0.8, "{m:?}");
        }
    }
}

#[test]
fn flat_direction_keeps_the_prediction() {
    // Two long parallel walls (a street): x is unobservable, the prior keeps it.
    let opts = MapOptions::default();
    let mut grid = OccupancyGrid::new(&opts).unwrap();
    let street = |half_len: i32| {
        let mut points = Vec::new();
        for k in -half_len..=half_len {
            let x = f64::from(k) * 0.1 + 0.05;
            points.extend([[x, -5.95], [x, 6.05]]);
        }
        PlanarScan::hits_from_origin(&points)
    };
    // The map's walls run beyond the scan's ends: x is unobservable.
    let mut scratch = crate::map::InsertScratch::new();
    for _ in 0..3 {
        grid.insert_scan(&street(380), &mut scratch).unwrap();
    }
    let scan = street(250);
    let (field, pts) = field_and_points(&grid, &scan, (400, 100), 1);
    let params = MatchParams::new(opts.resolution_m, &search());
    let predicted = Pose2::new(0.137, 0.02, 0.0);
    let m = match_scan(
        &field,
        &pts,
        &predicted,
        &params,
        &mut MatchScratch::default(),
    );
    assert!((m.pose.x_m - 0.137).abs() < 0.02, "{m:?}");
    assert!(m.pose.y_m.abs() < 0.02, "{m:?}");
}

/// `match_scan` as first written (gathers per offset, libm floor, four bounds checks per
/// interpolation): the optimised kernel must give bit-identical results.
fn match_scan_reference(
    field: &LikelihoodField,
    points_body: &[[f64; 2]],
    predicted: &Pose2,
    params: &MatchParams,
) -> MatchResult {
    let n = points_body.len().max(1) as f64;
    let limits = field.limits.unwrap();
    let res = params.resolution_m;
    let r = params.xy_radius_cells.max(0);
    let (w, h) = (field.w as i32, field.h as i32);
    let side = (2 * r + 1) as usize;
    let mut best = (f64::NEG_INFINITY, 0i32, 0i32, 0.0f64);
    let mut base = Vec::new();
    for &dyaw in &params.yaw_offsets_rad {
        let (s, c) = (predicted.yaw_rad + dyaw).sin_cos();
        base.clear();
        for p in points_body {
            let x = predicted.x_m + c * p[0] - s * p[1];
            let y = predicted.y_m + s * p[0] + c * p[1];
            let cell = limits.cell_of(x, y);
            let (li, lj) = (cell.i - field.i0, cell.j - field.j0);
            if li >= r && lj >= r && li < w - r && lj < h - r {
                base.push((lj - r) as usize * field.w + (li - r) as usize);
            }
        }
        for oy in 0..side {
            for ox in 0..side {
                let off = oy * field.w + ox;
                let sum: u32 = base.iter().map(|&b| u32::from(field.values[b + off])).sum();
                let (dx, dy) = (ox as i32 - r, oy as i32 - r);
                let obj = params.gain_per_unit * f64::from(sum)
                    - prior_penalty(params, f64::from(dx) * res, f64::from(dy) * res, dyaw);
                if obj > best.0 {
                    best = (obj, dx, dy, dyaw);
                }
            }
        }
    }
    let mut dx = f64::from(best.1) * res;
    let mut dy = f64::from(best.2) * res;
    let mut dyaw = best.3;
    let eval = |dx: f64, dy: f64, dyaw: f64| {
        let pose = Pose2::new(
            predicted.x_m + dx,
            predicted.y_m + dy,
            predicted.yaw_rad + dyaw,
        );
        let (s, c) = pose.yaw_rad.sin_cos();
        let sum: f64 = points_body
            .iter()
            .map(|p| {
                let x = pose.x_m + c * p[0] - s * p[1];
                let y = pose.y_m + s * p[0] + c * p[1];
                let (u, v) = limits.cell_coords(x, y);
                field.bilinear_reference(u, v)
            })
            .sum();
        (
            params.gain_per_unit * sum - prior_penalty(params, dx, dy, dyaw),
            sum,
        )
    };
    let (mut obj, mut sum) = eval(dx, dy, dyaw);
    let mut step_xy = 0.5 * res;
    let mut step_yaw = 0.5 * params.yaw_step_rad;
    let mut level = 0;
    let mut iterations = 0;
    while level < params.refine_levels && iterations < 64 {
        iterations += 1;
        let mut moved = None;
        for (ex, ey, eyaw) in [
            (step_xy, 0.0, 0.0),
            (-step_xy, 0.0, 0.0),
            (0.0, step_xy, 0.0),
            (0.0, -step_xy, 0.0),
            (0.0, 0.0, step_yaw),
            (0.0, 0.0, -step_yaw),
        ] {
            let cand = eval(dx + ex, dy + ey, dyaw + eyaw);
            if cand.0 > moved.map_or(obj, |m: (f64, f64, f64, f64, f64)| m.0) {
                moved = Some((cand.0, cand.1, dx + ex, dy + ey, dyaw + eyaw));
            }
        }
        match moved {
            Some((o, s, x, y, a)) => {
                obj = o;
                sum = s;
                dx = x;
                dy = y;
                dyaw = a;
            }
            None => {
                step_xy *= 0.5;
                step_yaw *= 0.5;
                level += 1;
            }
        }
    }
    MatchResult {
        pose: Pose2::new(
            predicted.x_m + dx,
            predicted.y_m + dy,
            predicted.yaw_rad + dyaw,
        ),
        objective: obj,
        fit: sum / (255.0 * n),
    }
}

/// The field build as first written (one pass over the window, then the kernels).
fn field_values_reference(
    grid: &OccupancyGrid,
    rect: &CellRect,
    sigma_m: f64,
    unknown_value: f64,
) -> Vec<u8> {
    let sigma_cells = (sigma_m / grid.limits().resolution_m()).max(0.25);
    let r = (3.0 * sigma_cells).ceil().min(16.0) as i32;
    let (w, h) = (rect.width() as i32, rect.height() as i32);
    let unknown = (255.0 * unknown_value.clamp(0.0, 1.0)).round() as u8;
    let mut values = vec![unknown; (w * h) as usize];
    let mut occupied = Vec::new();
    grid.for_each_observed_in(&rect.expanded(r), |c, v| {
        let (li, lj) = (c.i - rect.min_i, c.j - rect.min_j);
        if li >= 0 && lj >= 0 && li < w && lj < h {
            values[(lj * w + li) as usize] = 0;
        }
        if v >= grid.fixed().occupied {
            occupied.push((li, lj));
        }
    });
    for (li, lj) in occupied {
        for dj in -r..=r {
            for di in -r..=r {
                let d2 = f64::from(di * di + dj * dj);
                let v = (255.0 * (-0.5 * d2 / (sigma_cells * sigma_cells)).exp()).round();
                let (x, y) = (li + di, lj + dj);
                if v >= 1.0 && x >= 0 && y >= 0 && x < w && y < h {
                    let slot = &mut values[(y * w + x) as usize];
                    *slot = (*slot).max(v as u8);
                }
            }
        }
    }
    values
}

#[test]
fn banded_field_build_equals_the_plain_rule() {
    use rand::{RngExt, SeedableRng};
    let mut grid = OccupancyGrid::new(&MapOptions::default()).unwrap();
    let mut world = PlanarScan::default();
    let mut scratch = crate::map::InsertScratch::new();
    to_world(&room_scan(), &Pose2::new(0.0, 0.0, 0.0), &mut world);
    grid.insert_scan(&world, &mut scratch).unwrap();
    to_world(&room_scan(), &Pose2::new(0.3, 0.1, 0.02), &mut world);
    grid.insert_scan(&world, &mut scratch).unwrap();
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
    let mut field = LikelihoodField::new();
    for case in 0..40 {
        // Windows of 1 to ~150 rows (several bands, partial last bands), cutting walls.
        let (min_i, min_j) = (rng.random_range(-80..20), rng.random_range(-80..20));
        let rect = CellRect {
            min_i,
            min_j,
            max_i: min_i + rng.random_range(0..150),
            max_j: min_j + rng.random_range(0..150),
        };
        let (sigma, unknown) = (rng.random_range(0.03..0.5), [0.0, 0.5, 1.0][case % 3]);
        field.build(&grid, &rect, sigma, unknown);
        let want = field_values_reference(&grid, &rect, sigma, unknown);
        assert_eq!(&field.values[..want.len()], &want[..], "case {case}");
        assert_eq!(field.values.len(), want.len() + FIELD_PAD);
    }
}

#[test]
fn optimised_kernel_equals_the_reference_bit_for_bit() {
    use rand::{RngExt, SeedableRng};
    let opts = MapOptions::default();
    let mut grid = OccupancyGrid::new(&opts).unwrap();
    let scan = room_scan();
    let mut world = PlanarScan::default();
    let mut scratch = crate::map::InsertScratch::new();
    for k in 0..3 {
        to_world(
            &scan,
            &Pose2::new(0.01 * f64::from(k), 0.0, 0.0),
            &mut world,
        );
        grid.insert_scan(&world, &mut scratch).unwrap();
    }
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
    let mut field = LikelihoodField::new();
    let mut ms = MatchScratch::default();
    for case in 0..60 {
        // Windows that cut through the room too (points near and beyond the edges).
        let half_i = rng.random_range(20..80);
        let half_j = rng.random_range(20..70);
        let rect = CellRect {
            min_i: -half_i,
            min_j: -half_j,
            max_i: half_i,
            max_j: half_j,
        };
        let unknown = [0.0, 0.5, 1.0][case % 3];
        field.build(&grid, &rect, rng.random_range(0.05..0.3), unknown);
        let mut pts = Vec::new();
        match_points(&scan, rng.random_range(3.0..40.0), 1 + case % 3, &mut pts);
        let o = MatchSearch {
            xy_radius_cells: rng.random_range(0..6),
            yaw_search_deg: rng.random_range(0.0..2.0),
            prior_sigma_xy_m: rng.random_range(0.01..1.0),
            refine_levels: rng.random_range(0..5),
            ..search()
        };
        // The reference is f64 throughout.
        let params = MatchParams {
            kernel_precision: KernelPrecision::F64,
            ..MatchParams::new(0.1, &o)
        };
        let predicted = Pose2::new(
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.05..0.05),
        );
        let want = match_scan_reference(&field, &pts, &predicted, &params);
        let got = match_scan(&field, &pts, &predicted, &params, &mut ms);
        assert_eq!(
            got.pose.x_m.to_bits(),
            want.pose.x_m.to_bits(),
            "case {case}"
        );
        assert_eq!(
            got.pose.y_m.to_bits(),
            want.pose.y_m.to_bits(),
            "case {case}"
        );
        assert_eq!(got.pose.yaw_rad.to_bits(), want.pose.yaw_rad.to_bits());
        assert_eq!(
            got.objective.to_bits(),
            want.objective.to_bits(),
            "case {case}"
        );
        assert_eq!(got.fit.to_bits(), want.fit.to_bits(), "case {case}");
        // and the interpolation itself, everywhere including outside the window
        for _ in 0..200 {
            let (u, v) = (
                rng.random_range(-100.0..100.0),
                rng.random_range(-90.0..90.0),
            );
            assert_eq!(
                field.bilinear(u, v).to_bits(),
                field.bilinear_reference(u, v).to_bits()
            );
        }
    }
}

/// The f32 kernel's rotated points, filled in AVX2, equal [`RotationF32::block`]'s bit
/// for bit: 0-50 points (whole blocks and a padded last one), coordinates from
/// millimetres to 1e7 m, signed zeros, any yaw.
#[test]
fn rotated_f32_points_equal_the_scalar_fill_bit_for_bit() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(17);
    let mut rot = RotationF32::default();
    for case in 0..2000 {
        let n = rng.random_range(0..=50usize);
        let scale = [1e-3, 1.0, 80.0, 1e7][case % 4];
        let points: Vec<[f64; 2]> = (0..n)
            .map(|_| {
                if rng.random_range(0..20) == 0 {
                    [-0.0, 0.0]
                } else {
                    [
                        rng.random_range(-scale..scale),
                        rng.random_range(-scale..scale),
                    ]
                }
            })
            .collect();
        let (s, c) = rng.random_range(-4.0..4.0f64).sin_cos();
        let inv_res = [10.0, 20.0, 1.0 / 0.07][case % 3];
        rot.fill(&points, s, c, inv_res);
        let want: Vec<[[f32; LANES32]; 2]> = points
            .chunks(LANES32)
            .map(|chunk| RotationF32::block(chunk, s, c, inv_res))
            .collect();
        assert_eq!(rot.blocks.len(), want.len(), "case {case}");
        for (got, want) in rot.blocks.iter().zip(&want) {
            for (g, w) in got.as_flattened().iter().zip(want.as_flattened()) {
                assert_eq!(g.to_bits(), w.to_bits(), "case {case}");
            }
        }
        let last = if n % LANES32 == 0 {
            LANES32
        } else {
            n % LANES32
        };
        assert_eq!(rot.last_valid, last, "case {case}");
    }
}

/// The AVX2 kernels against the portable ones, bit for bit: the refinement's field sum
/// and the coarse search's window indices and block sums, with points inside the window,
/// across its edges, far outside it (beyond the fast path's 1e9 cells) and NaN.
#[test]
fn vector_kernels_equal_the_portable_ones_bit_for_bit() {
    use rand::{RngExt, SeedableRng};
    if !crate::kernels::cpu().avx2() {
        eprintln!("SKIP: no AVX2 on this CPU");
        return;
    }
    let (field, _) = room_field(0.0);
    let limits = field.limits.unwrap();
    assert!(field.vector_ok());
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(11);
    let mut rot = Rotation::default();
    let (mut want, mut got) = (Vec::new(), Vec::new());
    for case in 0..300 {
        let n = if case % 10 == 0 {
            700
        } else {
            rng.random_range(0..40)
        };
        let pts = kernel_points(&mut rng, n);
        let pose = Pose2::new(
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.3..0.3),
        );
        let (s, c) = pose.yaw_rad.sin_cos();
        rot.fill(&pts, s, c);
        let portable = rot.sum_portable(&field.window(), &limits, pose.x_m, pose.y_m);
        let [vector] = Rotation::sums([&rot], [[pose.x_m, pose.y_m]], &field.window(), &limits);
        assert_eq!(vector.to_bits(), portable.to_bits(), "case {case}");
        let r = rng.random_range(0..5);
        want.clear();
        let coarse = CoarseYaw {
            field: field.window(),
            limits: &limits,
            predicted: &pose,
            sin_cos: (s, c),
            r,
        };
        coarse.bases_portable(&pts, &mut want);
        coarse.bases(&pts, &mut got);
        assert_eq!(got, want, "case {case}");
        let w = field.w;
        macro_rules! sums {
            ($side:literal) => {
                if 2 * r + 1 == $side {
                    let mut plain = vec![0u32; $side * $side];
                    let mut swar = plain.clone();
                    let mut vector = plain.clone();
                    coarse_sums::<$side>(&field.values, w, &want, &mut plain);
                    coarse_sums_swar::<$side>(&field.values, w, &want, &mut swar);
                    coarse_sums_fast::<$side>(&field.values, w, &want, &mut vector);
                    assert_eq!(swar, plain, "case {case}");
                    assert_eq!(vector, plain, "case {case}");
                }
            };
        }
        sums!(3);
        sums!(5);
        sums!(7);
    }
}

/// Asserts that `batched` sums `field` at all of `cands` in one call with the bits `fresh`
/// gives one candidate at a time.
fn assert_batch_sums_alone(
    batched: &mut RotatedPoints,
    fresh: &mut RotatedPoints,
    field: &LikelihoodField,
    pts: &[[f64; 2]],
    cands: &[(Pose2, bool)],
    case: usize,
) {
    let limits = field.limits.unwrap();
    let mut got = vec![0.0; cands.len()];
    batched.field_sums(field, &limits, pts, cands, &mut got);
    for (i, (pose, keep)) in cands.iter().enumerate() {
        let one = fresh.field_sum(field, &limits, pts, pose, *keep);
        assert_eq!(got[i].to_bits(), one.to_bits(), "case {case} cand {i}");
    }
}

/// Random body points for the kernel tests: mostly inside the room's field, some across
/// its edges, far outside it (beyond the fast path's 1e9 cells) and NaN.
fn kernel_points(rng: &mut rand_xoshiro::Xoshiro256PlusPlus, n: usize) -> Vec<[f64; 2]> {
    use rand::RngExt;
    (0..n)
        .map(|_| match rng.random_range(0..40) {
            0 => [1e12, -3.0],
            1 => [f64::NAN, 1.0],
            2 => [rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0)],
            _ => [rng.random_range(-7.5..7.5), rng.random_range(-6.5..6.5)],
        })
        .collect()
}

/// The batched field sums (1..=6 candidates per pass, the portable and the AVX2 kernel,
/// candidates sharing a rotation or not) against the single-candidate sum as first
/// written, bit for bit; and `RotatedPoints::field_sums` (any number of candidates,
/// any mix of yaws and `keep` flags) against `field_sum` one candidate at a time.
#[test]
fn batched_field_sums_equal_the_single_candidate_ones_bit_for_bit() {
    use rand::{RngExt, SeedableRng};
    let (field, _) = room_field(0.0);
    let limits = field.limits.unwrap();
    let avx2 = field.vector_ok() && crate::kernels::cpu().avx2();
    if !avx2 {
        eprintln!("SKIP (AVX2 part only): no AVX2 on this CPU");
    }
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(23);
    let mut rotations: Vec<Rotation> = (0..3).map(|_| Rotation::default()).collect();
    let mut fresh = RotatedPoints::take(&mut RotationBuffers::default(), KernelPrecision::F64);
    let mut batched = RotatedPoints::take(&mut RotationBuffers::default(), KernelPrecision::F64);
    for case in 0..300 {
        let n = if case % 10 == 0 {
            700
        } else {
            rng.random_range(0..40)
        };
        let pts = kernel_points(&mut rng, n);
        for r in &mut rotations {
            let (s, c) = rng.random_range(-0.3..0.3f64).sin_cos();
            r.fill(&pts, s, c);
        }
        let k = 1 + case % NEIGHBOURS;
        // Candidates: a rotation each (often the same one, as the x/y moves) and a
        // position, some of them far outside.
        let rots: Vec<&Rotation> = (0..k)
            .map(|_| &rotations[rng.random_range(0..rotations.len())])
            .collect();
        let at: Vec<[f64; 2]> = (0..k)
            .map(|_| match rng.random_range(0..20) {
                0 => [2e9, 0.0],
                _ => [rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5)],
            })
            .collect();
        let want: Vec<u64> = rots
            .iter()
            .zip(&at)
            .map(|(r, a)| {
                r.sum_portable(&field.window(), &limits, a[0], a[1])
                    .to_bits()
            })
            .collect();
        macro_rules! check {
            ($k:literal) => {
                if k == $k {
                    let r: [&Rotation; $k] = std::array::from_fn(|i| rots[i]);
                    let a: [[f64; 2]; $k] = std::array::from_fn(|i| at[i]);
                    let got = Rotation::sums_portable(r, a, &field.window(), &limits);
                    assert_eq!(got.map(f64::to_bits).to_vec(), want, "case {case}");
                    // The AVX2 kernel where the CPU has it.
                    let got = Rotation::sums(r, a, &field.window(), &limits);
                    assert_eq!(got.map(f64::to_bits).to_vec(), want, "case {case}");
                }
            };
        }
        check!(1);
        check!(2);
        check!(3);
        check!(4);
        check!(5);
        check!(6);
        // Whole candidate lists through the rotation buffers: a pattern-search
        // iteration's shape (four x/y moves at one yaw, two yaw moves) and random mixes
        // of up to 9 candidates over up to 5 yaws (more one-off yaws than buffers).
        let base_yaw = rng.random_range(-0.3..0.3);
        let m = rng.random_range(1..10);
        let cands: Vec<(Pose2, bool)> = (0..m)
            .map(|i| {
                let (x, y) = (rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5));
                if case % 2 == 0 && m >= NEIGHBOURS {
                    let yaw = [0.0, 0.0, 0.0, 0.0, 0.002, -0.002][i % NEIGHBOURS];
                    (Pose2::new(x, y, base_yaw + yaw), i % NEIGHBOURS < 4)
                } else {
                    let yaw = base_yaw + 0.01 * f64::from(rng.random_range(0..5));
                    (Pose2::new(x, y, yaw), rng.random_bool(0.5))
                }
            })
            .collect();
        assert_batch_sums_alone(&mut batched, &mut fresh, &field, &pts, &cands, case);
    }
}

/// The f32 kernel: its AVX2 version gives the portable one's bits (1..=6 candidates
/// per pass, points across the window's edge, far outside it and NaN), its batched
/// sums through `RotatedPoints` are each candidate's own, and its sums lie within
/// 1e-5 x 255 per point (1e-5 of full scale) of the f64 kernel's, on finite points of
/// the room field's window and positions up to 2 m off (the window's coordinates then
/// reach ~140 cells, f32's resolution there is ~8e-6 cell).
#[test]
fn f32_kernel_agrees_with_the_f64_one_and_its_avx2_version_with_the_portable_bit_for_bit() {
    use rand::{RngExt, SeedableRng};
    let (field, _) = room_field(0.0);
    let limits = field.limits.unwrap();
    assert!(field.f32_ok());
    let avx2 = field.vector_ok() && crate::kernels::cpu().avx2();
    if !avx2 {
        eprintln!("SKIP (AVX2 part only): no AVX2 on this CPU");
    }
    let inv_res = 1.0 / limits.resolution_m();
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(31);
    let mut rot64 = Rotation::default();
    let mut rot32: Vec<RotationF32> = (0..3).map(|_| RotationF32::default()).collect();
    let mut fresh = RotatedPoints::take(&mut RotationBuffers::default(), KernelPrecision::F32);
    let mut batched = RotatedPoints::take(&mut RotationBuffers::default(), KernelPrecision::F32);
    let mut worst = 0.0f64;
    for case in 0..300 {
        let n = if case % 10 == 0 {
            700
        } else {
            rng.random_range(0..40)
        };
        // Odd cases: finite points (the tolerance part); even: with far and NaN ones.
        let pts: Vec<[f64; 2]> = if case % 2 == 1 {
            (0..n)
                .map(|_| [rng.random_range(-7.5..7.5), rng.random_range(-6.5..6.5)])
                .collect()
        } else {
            kernel_points(&mut rng, n)
        };
        let yaws: Vec<f64> = (0..3).map(|_| rng.random_range(-0.3..0.3)).collect();
        for (r, &yaw) in rot32.iter_mut().zip(&yaws) {
            let (s, c) = yaw.sin_cos();
            r.fill(&pts, s, c, inv_res);
        }
        let k = 1 + case % NEIGHBOURS;
        let pick: Vec<usize> = (0..k).map(|_| rng.random_range(0..3)).collect();
        let at_m: Vec<[f64; 2]> = (0..k)
            .map(|_| match rng.random_range(0..20) {
                0 if case % 2 == 0 => [2e9, 0.0],
                _ => [rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0)],
            })
            .collect();
        let at: Vec<[f32; 2]> = at_m
            .iter()
            .map(|a| field.f32_origin(&limits, a[0], a[1]))
            .collect();
        macro_rules! check {
            ($k:literal) => {
                if k == $k {
                    let r: [&RotationF32; $k] = std::array::from_fn(|i| &rot32[pick[i]]);
                    let a: [[f32; 2]; $k] = std::array::from_fn(|i| at[i]);
                    let portable = RotationF32::sums_portable(r, a, &field.window());
                    if avx2 {
                        let got = RotationF32::sums(r, a, &field.window());
                        assert_eq!(
                            got.map(f64::to_bits),
                            portable.map(f64::to_bits),
                            "case {case}"
                        );
                    }
                    // Each candidate's bits do not depend on its batch.
                    for i in 0..$k {
                        let [alone] = RotationF32::sums_portable([r[i]], [a[i]], &field.window());
                        assert_eq!(alone.to_bits(), portable[i].to_bits(), "case {case}");
                    }
                    if case % 2 == 1 {
                        for i in 0..$k {
                            let (s, c) = yaws[pick[i]].sin_cos();
                            rot64.fill(&pts, s, c);
                            let f64_sum = rot64.sum_portable(
                                &field.window(),
                                &limits,
                                at_m[i][0],
                                at_m[i][1],
                            );
                            let diff = (portable[i] - f64_sum).abs();
                            let tol = 1e-5 * 255.0 * n as f64;
                            worst = worst.max(diff / (255.0 * n.max(1) as f64));
                            assert!(
                                diff <= tol,
                                "case {case}: f32 {} f64 {f64_sum} ({n} points)",
                                portable[i]
                            );
                        }
                    }
                }
            };
        }
        check!(1);
        check!(2);
        check!(3);
        check!(4);
        check!(5);
        check!(6);
        let m = rng.random_range(1..10);
        let cands: Vec<(Pose2, bool)> = (0..m)
            .map(|_| {
                let yaw = yaws[0] + 0.01 * f64::from(rng.random_range(0..5));
                let (x, y) = (rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5));
                (Pose2::new(x, y, yaw), rng.random_bool(0.5))
            })
            .collect();
        assert_batch_sums_alone(&mut batched, &mut fresh, &field, &pts, &cands, case);
    }
    eprintln!("worst |f32 - f64| per point / 255: {worst:.3e}");
}

/// The batched pattern search evaluates the same positions in the same order (the
/// memo's hits, repeats within an iteration included) and returns the same bits as the
/// sequential one, on pure objectives with ties, NaN values and degenerate steps.
#[test]
fn batched_pattern_search_moves_as_the_sequential_one() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
    for case in 0..3000 {
        let centre: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
        let quantum = [0.0, 1e-3, 0.1, 1.0][case % 4];
        let nan_at = rng.random_range(0..30u64);
        let f = |p: [f64; 3]| -> (f64, f64) {
            let d = (p[0] - centre[0]).powi(2)
                + (p[1] - centre[1]).powi(2)
                + 4.0 * (p[2] - centre[2]).powi(2);
            // Plateaus (ties) when quantised; NaN at some positions.
            let o = if quantum > 0.0 {
                (-d / quantum).round() * quantum
            } else {
                -d
            };
            let hash = p.iter().fold(0u64, |h, v| h.rotate_left(7) ^ v.to_bits());
            let o = if hash % 31 == nan_at { f64::NAN } else { o };
            (o, d)
        };
        let start: [f64; 3] = match case % 7 {
            // Everything on a lattice of exact steps: many repeated positions.
            0 => [0.0, -0.0, 0.0],
            1 => [1e20, 0.5, -0.0],
            _ => std::array::from_fn(|_| rng.random_range(-1.0..1.0)),
        };
        let steps = match case % 5 {
            0 => (0.0, 0.0),
            1 => (1e-30, 0.25),
            2 => (0.25, 0.0),
            _ => (rng.random_range(0.01..0.5), rng.random_range(0.001..0.1)),
        };
        let levels = rng.random_range(0..6);
        let max_iterations = rng.random_range(1..80);
        let mut seq_calls = Vec::new();
        let want = pattern_search_sequential(
            start,
            f(start),
            steps.0,
            steps.1,
            levels,
            max_iterations,
            |at, same_yaw| {
                seq_calls.push((at.map(f64::to_bits), same_yaw));
                f(at)
            },
        );
        let mut batch_calls = Vec::new();
        let got = pattern_search(
            start,
            f(start),
            steps.0,
            steps.1,
            levels,
            max_iterations,
            |cands, values| {
                assert!(!cands.is_empty() && cands.len() <= NEIGHBOURS);
                assert_eq!(cands.len(), values.len());
                for (&(at, same_yaw), v) in cands.iter().zip(values) {
                    batch_calls.push((at.map(f64::to_bits), same_yaw));
                    *v = f(at);
                }
            },
        );
        assert_eq!(batch_calls, seq_calls, "case {case}");
        assert_eq!(
            got.0.map(f64::to_bits),
            want.0.map(f64::to_bits),
            "case {case}"
        );
        assert_eq!(got.1.0.to_bits(), want.1.0.to_bits(), "case {case}");
        assert_eq!(got.1.1.to_bits(), want.1.1.to_bits(), "case {case}");
    }
}

/// The room mapped three times (from x = 0, `step_m`, 2 `step_m`), its field over the
/// room, and the scan's matching points (every 2nd return).
fn room_field(step_m: f64) -> (LikelihoodField, Vec<[f64; 2]>) {
    let mut grid = OccupancyGrid::new(&MapOptions::default()).unwrap();
    let scan = room_scan();
    let mut world = PlanarScan::default();
    let mut scratch = crate::map::InsertScratch::new();
    for k in 0..3 {
        to_world(
            &scan,
            &Pose2::new(step_m * f64::from(k), 0.0, 0.0),
            &mut world,
        );
        grid.insert_scan(&world, &mut scratch).unwrap();
    }
    field_and_points(&grid, &scan, (70, 60), 2)
}

/// The field (sigma 0.15 m, unknown 0.5) over cells `-half..=half` of `grid`, and the
/// scan's matching points (up to 40 m, every `decimation`-th return).
fn field_and_points(
    grid: &OccupancyGrid,
    scan: &PlanarScan,
    (half_i, half_j): (i32, i32),
    decimation: usize,
) -> (LikelihoodField, Vec<[f64; 2]>) {
    let mut field = LikelihoodField::new();
    let rect = CellRect {
        min_i: -half_i,
        min_j: -half_j,
        max_i: half_i,
        max_j: half_j,
    };
    field.build(grid, &rect, 0.15, 0.5);
    let mut pts = Vec::new();
    match_points(scan, 40.0, decimation, &mut pts);
    (field, pts)
}
