//! The simulator's cameras: a built-in world rendered as the car's stereo pair (disparity and
//! texture map against the world's true ground colours) and as an RGB-D frame.
// Per-channel and per-pixel index loops read best in these checks.
#![allow(clippy::needless_range_loop)]

#[path = "../../pfslam-stereo/tests/support/disparity_stats.rs"]
mod disparity_stats;

use disparity_stats::DisparityStats;
use nalgebra::Vector3;
use pfslam::geometry::{Pose2, Rigid3};
use pfslam::map::{Cell, MapLimits};
use pfslam::sensors::StereoCalibration;
use pfslam_sim::{World, WorldScene};
use pfslam_stereo::image::BayerPattern;
use pfslam_stereo::{
    PinholeIntrinsics, RgbdCamera, RgbdFrame, StereoOptions, StereoPipeline, TextureMap,
    accumulate_rgbd,
};

#[test]
fn simulator_world_pair_disparity_and_texture() {
    let world = World::builtin("campus").unwrap();
    let scene = WorldScene::new(&world, 200.0);
    let calib = StereoCalibration::ucsd();
    // On the route, heading for the next waypoint.
    let (a, b) = (world.route[0], world.route[1]);
    let world_from_body = Pose2::new(a[0], a[1], (b[1] - a[1]).atan2(b[0] - a[0]));
    let (left, right) = scene
        .render_pair(&calib, &world_from_body, 2, BayerPattern::UCSD)
        .unwrap();
    let options = StereoOptions::default();
    let mut pipeline = StereoPipeline::new(&calib, &options).unwrap();
    pipeline.process_raw_pair(&left, &right).unwrap();
    let truth = scene.true_disparity(pipeline.geometry(), &world_from_body);
    let disparity = pipeline.disparity();
    DisparityStats::measure(&truth, disparity, &options)
        .check("campus world pair (ground and facades)");

    // Texture map (10 cm) against the world's true ground colours, 6-15 m ahead, 3.5 m either
    // side, over the cells the left camera actually sees.
    let limits = MapLimits::new(0.1, 0.0, 0.0);
    let mut map = TextureMap::new(limits);
    pipeline.accumulate(&world_from_body, &mut map);
    let camera = Rigid3::from_pose2(&world_from_body)
        .compose(&calib.body_from_camera)
        .translation;
    let body_from_world = world_from_body.inverse();
    let (mut cells, mut observed, mut err_sum) = (0usize, 0usize, 0.0f64);
    let here = limits.cell_of(world_from_body.x_m, world_from_body.y_m);
    for di in -200..200 {
        for dj in -200..200 {
            let cell = Cell::new(here.i + di, here.j + dj);
            let (cx, cy) = limits.cell_centre(cell);
            let (bx, by) = body_from_world.transform_point(cx, cy);
            if !(6.0..15.0).contains(&bx) || by.abs() > 3.5 {
                continue;
            }
            let target = Vector3::new(cx, cy, 0.0);
            let dist = (target - camera).norm();
            let seen = scene
                .range(&camera, &((target - camera) / dist))
                .is_some_and(|r| (r - dist).abs() < 0.05);
            if !seen {
                continue;
            }
            cells += 1;
            let Some(c) = map.get(cell) else { continue };
            observed += 1;
            let mut t = [0.0; 3];
            for j in 0..6 {
                for i in 0..6 {
                    let (x0, y0) = limits.cell_corner(cell);
                    let s = scene
                        .ground_rgb(x0 + (i as f64 + 0.5) / 60.0, y0 + (j as f64 + 0.5) / 60.0);
                    for k in 0..3 {
                        t[k] += s[k] / 36.0;
                    }
                }
            }
            err_sum += (0..3).map(|k| (c.mean[k] - t[k]).abs()).sum::<f64>() / 3.0;
        }
    }
    let coverage = observed as f64 / cells as f64;
    let mean_error = err_sum / observed as f64;
    eprintln!(
        "campus texture map: {cells} visible ground cells in the region, coverage {:.1} %, mean \
         |colour error| {mean_error:.2} (0-255 scale)",
        100.0 * coverage
    );
    assert!(cells > 3000, "{cells}");
    assert!(coverage > 0.9, "coverage {coverage}");
    assert!(mean_error < 10.0, "mean colour error {mean_error}");
}

#[test]
fn simulator_rgbd_frame_texture() {
    let world = World::builtin("office").unwrap();
    let scene = WorldScene::new(&world, 30.0);
    // A Kinect-like camera (VGA / 2) 1.2 m up, 30 deg down, on the route.
    let k = PinholeIntrinsics {
        width: 320,
        height: 240,
        fx_px: 290.0,
        fy_px: 290.0,
        cx_px: 160.0,
        cy_px: 120.0,
    };
    let pitch = 30f64.to_radians();
    let fwd = Vector3::new(pitch.cos(), 0.0, -pitch.sin());
    let right = Vector3::new(0.0, -1.0, 0.0);
    let body_from_camera = Rigid3 {
        rotation: nalgebra::Matrix3::from_columns(&[right, fwd.cross(&right), fwd]),
        translation: Vector3::new(0.0, 0.0, 1.2),
    };
    let (a, b) = (world.route[0], world.route[1]);
    let world_from_body = Pose2::new(a[0], a[1], (b[1] - a[1]).atan2(b[0] - a[0]));
    let world_from_camera = Rigid3::from_pose2(&world_from_body).compose(&body_from_camera);
    let (depth, colour) = scene.render_rgbd(&k, &world_from_camera);
    let camera = RgbdCamera {
        depth: k,
        colour: k,
        colour_from_depth: Rigid3::IDENTITY,
    };
    let limits = MapLimits::new(0.05, 0.0, 0.0);
    let mut map = TextureMap::new(limits);
    let mut points = Vec::new();
    let frame = RgbdFrame {
        depth_m: &depth,
        colour: &colour,
        camera: &camera,
        body_from_depth: &body_from_camera,
        world_from_body: &world_from_body,
    };
    let added = accumulate_rgbd(&frame, &StereoOptions::default(), &mut points, &mut map);
    // Every coloured cell against the true ground colour (mean over the cell).
    let mut err_sum = 0.0;
    let mut n = 0usize;
    for (&cell, c) in &map.cells {
        if c.count < 4 {
            continue;
        }
        let (x0, y0) = limits.cell_corner(cell);
        let mut t = [0.0; 3];
        for j in 0..6 {
            for i in 0..6 {
                let s =
                    scene.ground_rgb(x0 + (i as f64 + 0.5) / 120.0, y0 + (j as f64 + 0.5) / 120.0);
                for q in 0..3 {
                    t[q] += s[q] / 36.0;
                }
            }
        }
        err_sum += (0..3).map(|q| (c.mean[q] - t[q]).abs()).sum::<f64>() / 3.0;
        n += 1;
    }
    let mean_error = err_sum / n as f64;
    eprintln!(
        "office RGB-D frame: {added} ground points, {} cells (5 cm), {n} with >= 4 samples, mean \
         |colour error| {mean_error:.2}",
        map.cells.len()
    );
    assert!(added > 20_000, "{added}");
    assert!(n > 1000, "{n}");
    assert!(mean_error < 5.0, "{mean_error}");
}
