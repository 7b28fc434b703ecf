//! Simulated drive with stereo -> `pfslam run` writes a texture whose colours match the
//! world's true ground (and `pfslam texture` along the ground truth, for comparison).

use super::pfslam;
use nalgebra::Vector3;
use pfslam::geometry::{Pose2, Rigid3};
use pfslam::map::{Cell, MapLimits};
use pfslam::sensors::StereoCalibration;
use pfslam_io::tum::read_tum;
use pfslam_io::ucsd::read_stereo_stamps;
use pfslam_sim::WorldScene;
use pfslam_sim::world::World;
use std::path::Path;

/// A float32 `.npy` file: (shape, data).
fn read_npy_f32(path: &Path) -> (Vec<usize>, Vec<f32>) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..6], b"\x93NUMPY");
    let len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = String::from_utf8_lossy(&bytes[10..10 + len]).into_owned();
    assert!(header.contains("'descr': '<f4'"), "{header}");
    let shape_text = header.split("'shape': (").nth(1).unwrap();
    let shape: Vec<usize> = shape_text[..shape_text.find(')').unwrap()]
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| s.trim().parse().unwrap())
        .collect();
    let data: Vec<f32> = bytes[10 + len..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    assert_eq!(data.len(), shape.iter().product::<usize>());
    (shape, data)
}

/// Texture quality against the true ground.
#[derive(Debug)]
struct TextureQuality {
    /// Ground cells the left camera sees 6-15 m ahead and within 3.5 m of the axis, at some
    /// pair's pose.
    visible: usize,
    /// Of those, the cells the texture coloured.
    coloured: usize,
    /// Mean over coloured cells of the mean |R,G,B error| (0-255).
    mean_error: f64,
}

/// Compares `dir/texture_rgb.npy` with the ground colours of `scene`. `pairs` gives, for each
/// stereo pair, the pose the texture was built with (`placed`) and the true pose. A texture
/// cell at `p` (placed frame) shows the true ground at `true * placed^-1 * p` of the first pair
/// whose view holds it: so with `placed == true` this is the plain world comparison, and with
/// an estimated trajectory it measures the texture pipeline alone (the colours consistent with
/// the poses it was given), not the trajectory's error.
fn texture_quality(dir: &Path, scene: &WorldScene, pairs: &[(Pose2, Pose2)]) -> TextureQuality {
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("texture.json")).unwrap()).unwrap();
    let res = meta["resolution_m"].as_f64().unwrap();
    let x0 = meta["lower_left_corner_m"][0].as_f64().unwrap();
    let y0 = meta["lower_left_corner_m"][1].as_f64().unwrap();
    let (shape, rgb) = read_npy_f32(&dir.join("texture_rgb.npy"));
    let (h, w) = (shape[0], shape[1]);
    let limits = MapLimits::new(res, x0, y0);
    let calib = StereoCalibration::ucsd();
    // Visible cells (placed frame) -> true_from_placed of the first pair that sees them.
    let mut cells = std::collections::BTreeMap::new();
    for (placed, true_pose) in pairs {
        let true_from_placed = true_pose.compose(&placed.inverse());
        let camera = Rigid3::from_pose2(true_pose)
            .compose(&calib.body_from_camera)
            .translation;
        let body_from_placed = placed.inverse();
        let here = limits.cell_of(placed.x_m, placed.y_m);
        let r = (16.0 / res) as i32;
        for di in -r..=r {
            for dj in -r..=r {
                let cell = Cell::new(here.i + di, here.j + dj);
                let (cx, cy) = limits.cell_centre(cell);
                let (bx, by) = body_from_placed.transform_point(cx, cy);
                if !(6.0..15.0).contains(&bx) || by.abs() > 3.5 {
                    continue;
                }
                let (tx, ty) = true_from_placed.transform_point(cx, cy);
                let target = Vector3::new(tx, ty, 0.0);
                let dist = (target - camera).norm();
                if scene
                    .range(&camera, &((target - camera) / dist))
                    .is_some_and(|r| (r - dist).abs() < 0.05)
                {
                    cells.entry(cell).or_insert(true_from_placed);
                }
            }
        }
    }
    let (mut coloured, mut err_sum) = (0usize, 0.0f64);
    for (cell, true_from_placed) in &cells {
        if cell.i < 0 || cell.j < 0 || cell.i as usize >= w || cell.j as usize >= h {
            continue;
        }
        let k = 3 * ((h - 1 - cell.j as usize) * w + cell.i as usize);
        let got = &rgb[k..k + 3];
        if got[0].is_nan() {
            continue;
        }
        // The true cell colour: the mean over a 6x6 grid of points in the cell.
        let (cx0, cy0) = limits.cell_corner(*cell);
        let mut truth = [0.0f64; 3];
        for j in 0..6 {
            for i in 0..6 {
                let (tx, ty) = true_from_placed.transform_point(
                    cx0 + (i as f64 + 0.5) * res / 6.0,
                    cy0 + (j as f64 + 0.5) * res / 6.0,
                );
                let s = scene.ground_rgb(tx, ty);
                for c in 0..3 {
                    truth[c] += s[c] / 36.0;
                }
            }
        }
        coloured += 1;
        err_sum += (0..3)
            .map(|c| (got[c] as f64 - truth[c]).abs())
            .sum::<f64>()
            / 3.0;
    }
    TextureQuality {
        visible: cells.len(),
        coloured,
        mean_error: err_sum / coloured.max(1) as f64,
    }
}

fn check_success(o: &std::process::Output) -> String {
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    stdout
}

#[test]
fn simulated_stereo_drive_run_writes_a_true_texture() {
    let tmp = tempfile::tempdir().unwrap();
    let sim = tmp.path().join("sim");
    // 24 s at 0.25 Hz: 6 pairs, 5 of them while driving (2 s standstill first).
    let o = pfslam()
        .args(["simulate", "--duration-s", "24", "--seed", "5"])
        .args(["--stereo-rate-hz", "0.25", "--out"])
        .arg(&sim)
        .output()
        .unwrap();
    check_success(&o);
    let stamps = read_stereo_stamps(&sim).unwrap();
    assert_eq!(stamps.len(), 6, "{stamps:?}");
    for s in &stamps {
        for side in ["left", "right"] {
            let p = sim.join(format!("stereo_images/stereo_{side}/{s}.png"));
            let img = pfslam_stereo::image::load_gray_png(&p).unwrap();
            assert_eq!((img.width, img.height), (1280, 560));
        }
    }

    let run = tmp.path().join("run");
    let o = pfslam()
        .args(["run", "--particles", "20", "--out"])
        .arg(&run)
        .arg(&sim)
        .output()
        .unwrap();
    let stdout = check_success(&o);
    for f in [
        "texture.png",
        "texture_rgb.npy",
        "texture_count.npy",
        "texture.json",
    ] {
        assert!(run.join(f).is_file(), "missing {f}\n{stdout}");
    }
    let gt_dir = tmp.path().join("gt");
    let o = pfslam()
        .arg("texture")
        .arg(&sim)
        .arg("--poses")
        .arg(sim.join("ground_truth.tum"))
        .arg("--out")
        .arg(&gt_dir)
        .output()
        .unwrap();
    check_success(&o);

    let world = World::builtin("campus").unwrap();
    let scene = WorldScene::new(&world, 200.0);
    let truth = read_tum(&sim.join("ground_truth.tum")).unwrap();
    let slam = read_tum(&run.join("trajectory.tum")).unwrap();
    let pose_pairs = |placed: &pfslam::geometry::Trajectory| -> Vec<(Pose2, Pose2)> {
        stamps
            .iter()
            .map(|&s| (placed.pose_at(s).unwrap(), truth.pose_at(s).unwrap()))
            .collect()
    };
    let true_pairs = pose_pairs(&truth);
    let slam_pairs = pose_pairs(&slam);
    let results = [
        (
            "ground truth",
            texture_quality(&gt_dir, &scene, &true_pairs),
        ),
        ("SLAM", texture_quality(&run, &scene, &slam_pairs)),
        // For the report only: SLAM's pose error shifts the colours in the world.
        (
            "SLAM (world frame)",
            texture_quality(&run, &scene, &true_pairs),
        ),
    ];
    for (label, q) in &results {
        eprintln!(
            "texture along the {label} trajectory: {} visible ground cells, coverage {:.1} %, \
             mean |colour error| {:.2} (0-255)",
            q.visible,
            100.0 * q.coloured as f64 / q.visible as f64,
            q.mean_error
        );
    }
    for (label, q) in &results[..2] {
        let coverage = q.coloured as f64 / q.visible as f64;
        assert!(q.visible > 15_000, "{label}: {q:?}");
        assert!(coverage > 0.8, "{label}: {q:?}");
        assert!(q.mean_error < 5.0, "{label}: {q:?}");
    }
}

#[test]
fn run_warns_and_keeps_the_slam_outputs_when_a_stereo_image_is_bad() {
    let tmp = tempfile::tempdir().unwrap();
    let sim = tmp.path().join("sim");
    let o = pfslam()
        .args([
            "simulate",
            "--duration-s",
            "3",
            "--stereo-rate-hz",
            "0.5",
            "--out",
        ])
        .arg(&sim)
        .output()
        .unwrap();
    check_success(&o);
    let stamps = read_stereo_stamps(&sim).unwrap();
    assert_eq!(stamps.len(), 2);
    let bad = sim.join(format!("stereo_images/stereo_right/{}.png", stamps[1]));
    std::fs::write(&bad, b"not a png").unwrap();
    let run = tmp.path().join("run");
    let o = pfslam()
        .args(["run", "--particles", "5", "--out"])
        .arg(&run)
        .arg(&sim)
        .output()
        .unwrap();
    check_success(&o);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("texture not written"), "{stderr}");
    assert!(stderr.contains(&format!("{}.png", stamps[1])), "{stderr}");
    assert!(run.join("trajectory.tum").is_file());
    assert!(!run.join("texture.png").exists());
}
