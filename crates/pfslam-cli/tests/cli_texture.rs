//! `pfslam texture` end to end on a rendered two-pair dataset.

use super::{pfslam, run_ok};
use pfslam::geometry::Pose2;
use pfslam::sensors::StereoCalibration;
use pfslam_stereo::image::{BayerPattern, encode_gray_png};
use pfslam_stereo::render::render_ground_pair;
use std::path::Path;

/// A red square (world x 8-10 m, y -1-1 m) on a textured grey ground.
fn ground(x: f64, y: f64) -> [f64; 3] {
    let n = ((x * 37.0).sin() * (y * 23.0).cos() + (x * 11.0 + y * 7.0).sin()) * 0.25 + 0.5;
    let g = 60.0 + 120.0 * n;
    if (8.0..10.0).contains(&x) && (-1.0..1.0).contains(&y) {
        [g * 1.4, g * 0.4, g * 0.3]
    } else {
        [g, g, g]
    }
}

fn make_dataset(dir: &Path) {
    let calib = StereoCalibration::ucsd();
    let left_dir = dir.join("stereo_images/stereo_left");
    let right_dir = dir.join("stereo_images/stereo_right");
    std::fs::create_dir_all(&left_dir).unwrap();
    std::fs::create_dir_all(&right_dir).unwrap();
    let mut tum = String::new();
    for (k, x) in [0.0, 1.0].iter().enumerate() {
        let stamp_ns = 1_000_000_000i64 + k as i64 * 100_000_000;
        let pose = Pose2::new(*x, 0.0, 0.0);
        let (l, r) =
            render_ground_pair(&calib, &pose, &ground, [150.0; 3], 1, BayerPattern::UCSD).unwrap();
        std::fs::write(
            left_dir.join(format!("{stamp_ns}.png")),
            encode_gray_png(&l).unwrap(),
        )
        .unwrap();
        std::fs::write(
            right_dir.join(format!("{stamp_ns}.png")),
            encode_gray_png(&r).unwrap(),
        )
        .unwrap();
        tum.push_str(&format!("{:.9} {x} 0 0 0 0 0 1\n", stamp_ns as f64 * 1e-9));
    }
    std::fs::write(dir.join("poses.tum"), tum).unwrap();
}

fn npy_shape(path: &Path) -> String {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..6], b"\x93NUMPY");
    let len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = String::from_utf8_lossy(&bytes[10..10 + len]).into_owned();
    assert_eq!((10 + len) % 64, 0);
    header
}

/// Runs `pfslam texture DIR --poses DIR/poses.tum --out DIR/out`, which must succeed.
fn run_texture(dir: &Path) -> std::path::PathBuf {
    let out_dir = dir.join("out");
    run_ok(
        pfslam()
            .arg("texture")
            .arg(dir)
            .arg("--poses")
            .arg(dir.join("poses.tum"))
            .arg("--out")
            .arg(&out_dir),
    );
    out_dir
}

#[test]
fn texture_colours_the_red_square() {
    let tmp = tempfile::tempdir().unwrap();
    make_dataset(tmp.path());
    let out_dir = run_texture(tmp.path());
    assert!(out_dir.join("texture.png").is_file());
    let header = npy_shape(&out_dir.join("texture_rgb.npy"));
    assert!(
        header.contains("'descr': '<f4'") && header.contains(", 3)"),
        "{header}"
    );
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("texture.json")).unwrap()).unwrap();
    assert_eq!(meta["pairs_used"], 2);
    assert_eq!(meta["background"], "plain grey (no LiDAR data)");
    // The red square's cells are red: read the float32 raster back.
    let bytes = std::fs::read(out_dir.join("texture_rgb.npy")).unwrap();
    let len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let data: Vec<f32> = bytes[10 + len..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let res = meta["resolution_m"].as_f64().unwrap();
    let x0 = meta["lower_left_corner_m"][0].as_f64().unwrap();
    let y0 = meta["lower_left_corner_m"][1].as_f64().unwrap();
    let w = meta["width_cells"].as_u64().unwrap() as usize;
    let h = meta["height_cells"].as_u64().unwrap() as usize;
    let (mut red, mut seen) = (0, 0);
    for row in 0..h {
        for col in 0..w {
            let x = x0 + (col as f64 + 0.5) * res;
            let y = y0 + ((h - 1 - row) as f64 + 0.5) * res;
            if !((8.2..9.8).contains(&x) && (-0.8..0.8).contains(&y)) {
                continue;
            }
            let i = 3 * (row * w + col);
            if data[i].is_nan() {
                continue;
            }
            seen += 1;
            if data[i] > 1.8 * data[i + 1] {
                red += 1;
            }
        }
    }
    assert!(seen > 200, "{seen}");
    assert!(red as f64 > 0.95 * seen as f64, "{red} of {seen}");
}

#[test]
fn texture_without_poses_file_exits_2() {
    let tmp = tempfile::tempdir().unwrap();
    let out = pfslam()
        .arg("texture")
        .arg(tmp.path())
        .arg("--poses")
        .arg(tmp.path().join("missing.tum"))
        .arg("--out")
        .arg(tmp.path().join("out"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn texture_over_the_lidar_map_of_a_simulated_drive() {
    use pfslam_io::tum::write_tum;
    use pfslam_io::ucsd::write_car_dataset;
    use pfslam_sim::SimOptions;
    use pfslam_sim::WorldScene;
    use pfslam_sim::car::simulate_car;
    use pfslam_sim::world::World;
    // A 6 s drive on the campus: the car's files (with LiDAR), two rendered stereo pairs.
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let opts = SimOptions {
        duration_s: 6.0,
        ..SimOptions::noise_free()
    };
    let world = World::builtin("campus").unwrap();
    let sim = simulate_car(&world, &opts).unwrap();
    write_car_dataset(dir, &sim.dataset).unwrap();
    write_tum(&dir.join("poses.tum"), &sim.ground_truth).unwrap();
    let scene = WorldScene::new(&world, 200.0);
    let calib = StereoCalibration::ucsd();
    for dir_name in ["stereo_images/stereo_left", "stereo_images/stereo_right"] {
        std::fs::create_dir_all(dir.join(dir_name)).unwrap();
    }
    let n = sim.ground_truth.len();
    for p in [&sim.ground_truth[n / 3], &sim.ground_truth[2 * n / 3]] {
        let (l, r) = scene
            .render_pair(&calib, &p.pose, 1, BayerPattern::UCSD)
            .unwrap();
        let name = format!("{}.png", p.stamp_ns);
        std::fs::write(
            dir.join("stereo_images/stereo_left").join(&name),
            encode_gray_png(&l).unwrap(),
        )
        .unwrap();
        std::fs::write(
            dir.join("stereo_images/stereo_right").join(&name),
            encode_gray_png(&r).unwrap(),
        )
        .unwrap();
    }
    let out_dir = run_texture(dir);
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("texture.json")).unwrap()).unwrap();
    assert_eq!(meta["background"], "occupancy map", "{meta}");
    assert_eq!(meta["pairs_used"], 2);
    assert!(meta["cells_coloured"].as_u64().unwrap() > 5000, "{meta}");
    assert!(out_dir.join("texture.png").is_file());
}
