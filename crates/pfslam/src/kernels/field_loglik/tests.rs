use super::{CentrePose, CentreTable, POSES, portable, sums4};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

const FLOOR: f32 = -7.5;

/// The likelihood field's scalar rule at cell-centre coordinates, the reference.
fn scalar_at(table: &CentreTable<'_>, u: f64, v: f64) -> f32 {
    let (i0, j0) = (u.floor(), v.floor());
    let (fx, fy) = ((u - i0) as f32, (v - j0) as f32);
    let (w, h) = (table.width as f64, table.height as f64);
    let at = |i: f64, j: f64| -> f32 {
        if i < 0.0 || j < 0.0 || i >= w || j >= h {
            FLOOR
        } else {
            table.cells[j as usize * table.width + i as usize]
        }
    };
    let (a, b) = (at(i0, j0), at(i0 + 1.0, j0));
    let (c, d) = (at(i0, j0 + 1.0), at(i0 + 1.0, j0 + 1.0));
    let low = a + fx * (b - a);
    let high = c + fx * (d - c);
    low + fy * (high - low)
}

/// The scan's sum at one pose by the scalar rule, point by point.
fn scalar_sum(table: &CentreTable<'_>, points: &[[f64; 2]], pose: &CentrePose) -> f64 {
    points
        .iter()
        .map(|p| {
            let (u, v) = pose.place(p);
            scalar_at(table, u, v) as f64
        })
        .sum()
}

/// Poses whose points fall inside, across the edges and far off a 37 x 23 table
/// (0.05 m cells), some exactly on whole cells.
fn random_pose(rng: &mut Xoshiro256PlusPlus, far: bool) -> CentrePose {
    let yaw = if rng.random::<bool>() {
        0.0
    } else {
        rng.random_range(-3.2..3.2f64)
    };
    let (s, c) = yaw.sin_cos();
    let span = if far { 6e9 } else { 45.0 };
    let mut centre = || {
        let x: f64 = rng.random_range(-span..span);
        if rng.random_range(0..4) == 0 {
            x.round()
        } else {
            x
        }
    };
    CentrePose {
        u0_cells: centre() * 0.5 + 18.0,
        v0_cells: centre() * 0.3 + 11.0,
        cs_per_m: c * 20.0,
        ss_per_m: s * 20.0,
    }
}

#[test]
fn kernels_match_the_scalar_rule_bit_for_bit() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    let (width, height) = (37, 23);
    let cells: Vec<f32> = (0..width * height)
        .map(|_| rng.random_range(-9.0..-0.5f32))
        .collect();
    let table = CentreTable {
        cells: &cells,
        width,
        height,
    };
    let off = |u: f64, v: f64| scalar_at(&table, u, v);
    for round in 0..400 {
        let n = round % 70;
        let points: Vec<[f64; 2]> = (0..n)
            .map(|_| {
                let p = [rng.random_range(-1.2..1.2), rng.random_range(-1.2..1.2)];
                if rng.random_range(0..5) == 0 {
                    p.map(|x: f64| (x * 20.0).round() / 20.0)
                } else {
                    p
                }
            })
            .collect();
        let poses: [CentrePose; POSES] =
            std::array::from_fn(|_| random_pose(&mut rng, round % 11 == 0));
        let want = poses.map(|p| scalar_sum(&table, &points, &p));
        let vector = sums4(&table, &points, poses, off);
        let plain = portable(&table, &points, poses, off);
        for k in 0..POSES {
            let [alone] = portable(&table, &points, [poses[k]], off);
            let bits = want[k].to_bits();
            assert_eq!(vector[k].to_bits(), bits, "{round} {k} vector");
            assert_eq!(plain[k].to_bits(), bits, "{round} {k} portable");
            assert_eq!(alone.to_bits(), bits, "{round} {k} alone");
        }
    }
}
