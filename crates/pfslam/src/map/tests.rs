//! Unit tests of the grid and insertion.

use super::*;
use proptest::prelude::*;

fn grid(res: f64) -> OccupancyGrid {
    OccupancyGrid::with_params(MapLimits::new(res, 0.0, 0.0), LogOddsParams::ucsd())
}

fn scan_at(sx: f64, sy: f64, pts: &[(f64, f64, bool)]) -> PlanarScan {
    PlanarScan {
        sensor_x_m: sx,
        sensor_y_m: sy,
        sensor_z_m: None,
        points: pts
            .iter()
            .map(|&(x_m, y_m, hit)| ScanPoint {
                x_m,
                y_m,
                hit,
                free_to: 1.0,
                z_m: 0.0,
            })
            .collect(),
    }
}

#[test]
fn unknown_until_written_and_negative_cells() {
    let mut g = grid(0.1);
    let c = Cell::new(-1000, 37);
    assert_eq!(g.logodds_fixed(c), 0);
    assert_eq!(g.state(c), CellState::Unknown);
    assert_eq!(g.probability(c), 0.5);
    g.update_occupied(c).unwrap();
    assert_eq!(g.state(c), CellState::Occupied);
    assert!((g.logodds(c) - 4f64.ln()).abs() < 0.01);
    assert!((g.probability(c) - 0.8).abs() < 1e-3);
    g.update_free(c).unwrap();
    g.update_free(c).unwrap();
    assert_eq!(g.state(c), CellState::Free);
    assert_eq!(g.tile_count(), 1);
    assert!(g.update_free(Cell::new(i32::MAX, 0)).is_err());
}

#[test]
fn clamped_in_the_grid() {
    let mut g = grid(0.1);
    let c = Cell::new(5, 5);
    for _ in 0..50 {
        g.update_occupied(c).unwrap();
    }
    assert!((g.logodds(c) - 10.0 * 4f64.ln()).abs() < 0.01);
}

#[test]
fn directory_grows_in_all_directions() {
    let mut g = grid(0.1);
    let cells = [
        Cell::new(0, 0),
        Cell::new(5000, -3),
        Cell::new(-7000, 9000),
        Cell::new(64, -6400),
        Cell::new(-1, -1),
    ];
    for (k, c) in cells.iter().enumerate() {
        g.set_fixed(*c, 100 + k as i16).unwrap();
    }
    for (k, c) in cells.iter().enumerate() {
        assert_eq!(g.logodds_fixed(*c), 100 + k as i16, "{c:?}");
    }
    assert_eq!(g.tile_count(), 5);
    let b = g.observed_bounds().unwrap();
    assert_eq!(
        (b.min_i, b.max_i, b.min_j, b.max_j),
        (-7000, 5000, -6400, 9000)
    );
}

#[test]
fn clone_shares_tiles_copy_on_write() {
    let mut a = grid(0.1);
    for k in 0..10 {
        a.update_occupied(Cell::new(k * 64, 0)).unwrap();
    }
    let mut b = a.clone();
    assert_eq!(b.shared_tiles_with(&a), 10);
    b.update_free(Cell::new(0, 0)).unwrap();
    assert_eq!(b.shared_tiles_with(&a), 9);
    assert_eq!(a.state(Cell::new(0, 0)), CellState::Occupied);
    assert_eq!(b.logodds_fixed(Cell::new(0, 0)), 0);
}

#[test]
fn insertion_rule_one_update_per_scan_occupied_wins() {
    let mut g = grid(1.0);
    let mut s = InsertScratch::new();
    // Three rays from (0.5, 0.5): two end in cell (5, 0); one passes through (5, 0) to (8, 0).
    let scan = scan_at(
        0.5,
        0.5,
        &[(5.5, 0.5, true), (5.2, 0.7, true), (8.5, 0.5, true)],
    );
    let st = g.insert_scan(&scan, &mut s).unwrap();
    assert_eq!(st.rays, 3);
    let f = *g.fixed();
    // cells 0..4 crossed by three rays: one free update each
    for i in 0..5 {
        assert_eq!(g.logodds_fixed(Cell::new(i, 0)), f.miss, "cell {i}");
    }
    // cell 5: end of two returns, crossed by the third: one occupied update
    assert_eq!(g.logodds_fixed(Cell::new(5, 0)), f.hit);
    assert_eq!(g.logodds_fixed(Cell::new(6, 0)), f.miss);
    assert_eq!(g.logodds_fixed(Cell::new(8, 0)), f.hit);
    assert_eq!(st.occupied_cells, 2);
    assert_eq!(st.free_cells, 7);
    // the scratch is left clean: a second insertion does exactly the same again
    let st2 = g.insert_scan(&scan, &mut s).unwrap();
    assert_eq!(st, st2);
    assert_eq!(g.logodds_fixed(Cell::new(5, 0)), 2 * f.hit);
    // ray order does not matter
    let mut g2 = grid(1.0);
    let mut rev = scan.clone();
    rev.points.reverse();
    g2.insert_scan(&rev, &mut InsertScratch::new()).unwrap();
    g2.insert_scan(&rev, &mut s).unwrap();
    let r = CellRect {
        min_i: -2,
        min_j: -2,
        max_i: 10,
        max_j: 2,
    };
    let (mut a, mut b) = (Vec::new(), Vec::new());
    g.copy_rect_fixed(&r, &mut a);
    g2.copy_rect_fixed(&r, &mut b);
    assert_eq!(a, b);
}

#[test]
fn no_return_ray_clears_without_occupying() {
    let mut g = grid(1.0);
    let scan = scan_at(0.5, 0.5, &[(0.5, 6.5, false)]);
    g.insert_scan(&scan, &mut InsertScratch::new()).unwrap();
    for j in 0..=6 {
        assert_eq!(g.state(Cell::new(0, j)), CellState::Free, "{j}");
    }
    assert_eq!(g.state(Cell::new(0, 7)), CellState::Unknown);
}

#[test]
fn too_long_or_far_scans_are_refused_unchanged() {
    let mut g = grid(0.001);
    let scan = scan_at(0.0, 0.0, &[(100.0, 0.0, true)]);
    assert!(matches!(
        g.insert_scan(&scan, &mut InsertScratch::new()),
        Err(MapError::RayTooLong { .. })
    ));
    let scan = scan_at(1e12, 0.0, &[]);
    assert!(matches!(
        g.insert_scan(&scan, &mut InsertScratch::new()),
        Err(MapError::OutOfRange { .. })
    ));
    assert_eq!(g.tile_count(), 0);
}

#[test]
fn options_validate_and_roundtrip() {
    let o = MapOptions::default();
    o.validate().unwrap();
    let text = toml::to_string(&o).unwrap();
    let back: MapOptions = toml::from_str(&text).unwrap();
    assert_eq!(o, back);
    let e: MapOptions = toml::from_str(
        "resolution_m = 0.05\n[log_odds]\nhit = 0.85\nmiss = -0.42\n[scan]\nno_return = \"clear_free\"\nz_min_m = 0.3\n",
    )
    .unwrap();
    assert_eq!(e.scan.no_return, NoReturnPolicy::ClearFree);
    assert_eq!(e.scan.z_min_m, Some(0.3));
    assert_eq!(e.log_odds.clamp_max, LogOddsParams::ucsd().clamp_max);
    assert!(toml::from_str::<MapOptions>("bogus = 1").is_err());
    let ese = MapOptions::default().with_preset(LogOddsPreset::Ese650);
    assert_eq!(ese.resolution_m, 0.1);
    assert_eq!(ese.log_odds, LogOddsParams::ese650());
    let bad = MapOptions {
        resolution_m: 0.001,
        ..MapOptions::default()
    };
    assert!(bad.validate().is_err());
    assert!(OccupancyGrid::new(&bad).is_err());
}

proptest! {
    #[test]
    fn world_cell_world_within_half_a_cell(
        x in -1e5f64..1e5, y in -1e5f64..1e5,
        res in 0.01f64..2.0, ox in -100f64..100.0, oy in -100f64..100.0,
    ) {
        let l = MapLimits::new(res, ox, oy);
        let c = l.cell_of(x, y);
        let (cx, cy) = l.cell_centre(c);
        prop_assert!((cx - x).abs() <= 0.5 * res * (1.0 + 1e-9));
        prop_assert!((cy - y).abs() <= 0.5 * res * (1.0 + 1e-9));
        prop_assert_eq!(l.cell_of(cx, cy), c);
    }

    #[test]
    fn bresenham_endpoints_and_connectivity(
        x0 in -500i32..500, y0 in -500i32..500, x1 in -500i32..500, y1 in -500i32..500,
    ) {
        let (a, b) = (Cell::new(x0, y0), Cell::new(x1, y1));
        let cells = bresenham_cells(a, b);
        prop_assert_eq!(cells[0], a);
        prop_assert_eq!(*cells.last().unwrap(), b);
        prop_assert_eq!(cells.len() as i32, (x1 - x0).abs().max((y1 - y0).abs()) + 1);
        for w in cells.windows(2) {
            let (di, dj) = ((w[1].i - w[0].i).abs(), (w[1].j - w[0].j).abs());
            prop_assert!(di <= 1 && dj <= 1 && di + dj >= 1);
        }
        // the line stays within half a cell of the true segment (perpendicular distance)
        let (dx, dy) = ((x1 - x0) as f64, (y1 - y0) as f64);
        let len = dx.hypot(dy);
        if len > 0.0 {
            for c in &cells {
                let d = (((c.i - x0) as f64) * dy - ((c.j - y0) as f64) * dx).abs() / len;
                prop_assert!(d <= 0.7072, "{:?} at {}", c, d);
            }
        }
    }

    #[test]
    fn insertion_is_order_independent(
        pts in proptest::collection::vec((-30f64..30.0, -30f64..30.0, any::<bool>()), 1..40),
        sx in -5f64..5.0, sy in -5f64..5.0,
    ) {
        let scan = scan_at(sx, sy, &pts);
        let mut rev = scan.clone();
        rev.points.reverse();
        let (mut a, mut b) = (grid(0.5), grid(0.5));
        let mut s = InsertScratch::new();
        a.insert_scan(&scan, &mut s).unwrap();
        b.insert_scan(&rev, &mut s).unwrap();
        let r = CellRect { min_i: -80, min_j: -80, max_i: 80, max_j: 80 };
        let (mut va, mut vb) = (Vec::new(), Vec::new());
        a.copy_rect_fixed(&r, &mut va);
        b.copy_rect_fixed(&r, &mut vb);
        prop_assert_eq!(va, vb);
        // every end cell of a return is occupied after one scan
        for p in scan.points.iter().filter(|p| p.hit) {
            prop_assert_eq!(a.state(a.cell_of(p.x_m, p.y_m)), CellState::Occupied);
        }
    }
}

/// A one-ray scan from a sensor at 1.76 m to `(x, 0)` at height `z_m`.
fn ray3(x: f64, z_m: f32, hit: bool) -> PlanarScan {
    PlanarScan {
        sensor_x_m: 0.05,
        sensor_y_m: 0.05,
        sensor_z_m: Some(1.76),
        points: vec![ScanPoint {
            x_m: x,
            y_m: 0.05,
            hit,
            free_to: 1.0,
            z_m,
        }],
    }
}

#[test]
fn height_bins_keep_a_roof_under_level_passes_in_any_order() {
    // A parked car's roof at 1.5 m, 5 m away, hit once by a dipping beam; level beams (1.76 m)
    // pass over it ten times on their way to a wall at 10 m.
    let roof = ray3(5.05, 1.5, true);
    let over = ray3(10.05, 1.76, true);
    let roof_cell = Cell::new(50, 0);
    let run = |opts: &MapOptions, roof_first: bool| {
        let mut g = OccupancyGrid::new(opts).unwrap();
        let mut s = InsertScratch::new();
        if roof_first {
            g.insert_scan(&roof, &mut s).unwrap();
        }
        for _ in 0..10 {
            g.insert_scan(&over, &mut s).unwrap();
        }
        if !roof_first {
            g.insert_scan(&roof, &mut s).unwrap();
        }
        g
    };
    let opts = MapOptions::default();
    let (a, b) = (run(&opts, true), run(&opts, false));
    assert_eq!(a.state(roof_cell), CellState::Occupied);
    // Order-independent: the same bins and 2-D values.
    let r = a.observed_bounds().unwrap();
    assert_eq!(Some(r), b.observed_bounds());
    let (mut va, mut vb) = (Vec::new(), Vec::new());
    a.copy_rect_fixed(&r, &mut va);
    b.copy_rect_fixed(&r, &mut vb);
    assert_eq!(va, vb);
    assert_eq!(a.height_bins(roof_cell), b.height_bins(roof_cell));
    let bins = a.height_bins(roof_cell).unwrap();
    assert_eq!(bins.iter().filter(|&&v| v > 0).count(), 1, "{bins:?}");
    assert_eq!(bins.iter().filter(|&&v| v < 0).count(), 1, "{bins:?}");
    // The cells passed only at 1.76 m are free, the wall occupied.
    assert_eq!(a.state(Cell::new(30, 0)), CellState::Free);
    assert_eq!(a.state(Cell::new(100, 0)), CellState::Occupied);
    // One log-odds value per cell (bins off): the passes vote the roof free.
    let mut flat = MapOptions::default();
    flat.height.enabled = false;
    let c = run(&flat, true);
    assert_eq!(c.state(roof_cell), CellState::Free);
    assert_eq!(c.height_tile_count(), 0);
    assert!(a.memory_bytes() > c.memory_bytes());
}

#[test]
fn level_scanners_never_use_height_bins() {
    // A level mount produces scans without heights: the grid takes the 2-D path, so maps of
    // level LiDARs are the same with and without `[map.height]`.
    let g = crate::sensors::LidarGeometry::ucsd_lms511();
    let level = crate::geometry::Rigid3::from_rpy(0.0, 0.0, 1.0, [0.3, 0.0, 0.4]);
    let p = ScanProjector::new(&g, &level, &ScanOptions::default()).unwrap();
    let ranges: Vec<f32> = (0..g.beam_count).map(|k| 3.0 + (k % 7) as f32).collect();
    let mut body = PlanarScan::default();
    p.to_body(&ranges, &mut body).unwrap();
    assert_eq!(body.sensor_z_m, None);
    let mut on = OccupancyGrid::new(&MapOptions::default()).unwrap();
    let mut off_opts = MapOptions::default();
    off_opts.height.enabled = false;
    let mut off = OccupancyGrid::new(&off_opts).unwrap();
    let mut world = PlanarScan::default();
    to_world(&body, &Pose2::new(3.0, -2.0, 0.4), &mut world);
    on.insert_scan(&world, &mut InsertScratch::new()).unwrap();
    off.insert_scan(&world, &mut InsertScratch::new()).unwrap();
    assert_eq!(on.height_tile_count(), 0);
    let r = on.observed_bounds().unwrap();
    let (mut va, mut vb) = (Vec::new(), Vec::new());
    on.copy_rect_fixed(&r, &mut va);
    off.copy_rect_fixed(&r, &mut vb);
    assert_eq!(va, vb);
    // The car's tilted mount does carry heights.
    let cal = crate::sensors::CarCalibration::ucsd();
    let p = ScanProjector::new(&cal.lidar, &cal.body_from_lidar, &ScanOptions::default()).unwrap();
    p.to_body(&ranges, &mut body).unwrap();
    assert!((body.sensor_z_m.unwrap() - 1.764).abs() < 1e-3);
}

#[test]
fn project_bins_rule() {
    let m = BinLogOdds::new(&LogOddsParams::ese650(), 0.7);
    let occ = LogOddsParams::ese650().to_fixed().occupied;
    assert_eq!((m.hit, m.miss, m.occupied), (14, -7, 14));
    assert_eq!(project_bins(&[0; 4], &m, occ), 0);
    // Any occupied bin: occupied, whatever the others.
    assert!(project_bins(&[-120, 14, 0, -7], &m, occ) >= occ);
    // None occupied: the most free observed bin.
    assert_eq!(project_bins(&[0, 7, -70, 0], &m, occ), -70 * 16);
    assert_eq!(project_bins(&[0, 7, 0, 0], &m, occ), 7 * 16);
}

#[test]
fn height_options_are_validated() {
    let mut o = MapOptions::default();
    o.height.bins = 17;
    assert!(o.validate().unwrap_err().contains("map.height.bins"));
    o.height.bins = 8;
    o.height.z_max_m = o.height.z_min_m;
    assert!(o.validate().is_err());
    o.height.z_max_m = 3.0;
    o.height.occupied_prob = Some(0.3);
    assert!(o.validate().is_err());
}
