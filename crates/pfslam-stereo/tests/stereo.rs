//! Stereo texture mapping: demosaicing, the real pair's road plane, a rendered ground plane's
//! disparity and colours, the RGB-D path.
// Per-channel and per-pixel index loops read best in these checks.
#![allow(clippy::needless_range_loop)]

#[path = "support/disparity_stats.rs"]
mod disparity_stats;

use disparity_stats::{DisparityStats, percentile};

use nalgebra::Vector3;
use pfslam::geometry::{Pose2, Rigid3};
use pfslam::map::{Cell, MapLimits};
use pfslam::sensors::StereoCalibration;
use pfslam_stereo::disparity::Aggregation;
use pfslam_stereo::image::{self, BayerPattern, Demosaic, RgbImage};
use pfslam_stereo::render::{ground_disparity, hash01, render_ground_pair, value_noise};
use pfslam_stereo::{
    MatcherOptions, PinholeIntrinsics, RgbdCamera, RgbdFrame, StereoOptions, StereoPipeline,
    TextureMap, accumulate_rgbd, fit_plane_ransac,
};

/// The synthetic ground: asphalt-like noise, three coloured areas and dashed lane markings,
/// laid out in the frame of `layout_from_world` (the test's body pose) so they are in view.
fn ground_texture(layout_from_world: &Pose2, x: f64, y: f64) -> [f64; 3] {
    let grey = 40.0 + 70.0 * value_noise(x, y, 0.04, 1) + 50.0 * value_noise(x, y, 0.15, 2);
    let (bx, by) = layout_from_world.transform_point(x, y);
    let in_box = |x0: f64, x1: f64, y0: f64, y1: f64| bx >= x0 && bx < x1 && by >= y0 && by < y1;
    let lane = ((by - 1.75).abs() < 0.08 || (by + 1.75).abs() < 0.08) && bx.rem_euclid(3.0) < 1.5;
    if lane {
        return [215.0, 215.0, 205.0].map(|c| c - 20.0 * value_noise(x, y, 0.04, 3));
    }
    let tint = if in_box(7.0, 9.5, -1.2, 0.8) {
        [1.6, 0.55, 0.45]
    } else if in_box(10.0, 13.0, 0.5, 3.0) {
        [0.5, 1.5, 0.6]
    } else if in_box(5.5, 8.0, 1.2, 3.5) {
        [0.6, 0.8, 1.7]
    } else {
        [1.0, 1.0, 1.0]
    };
    tint.map(|t| (t * grey).min(255.0))
}

/// RGB test images. `natural`: brightness edges, shading and fine texture under a smoothly
/// varying tint (the channels vary together, as in photographs of roads); otherwise
/// saturated colour patches with pure chroma edges (the adversarial case of
/// gradient-corrected demosaicing).
fn demosaic_test_image(width: usize, height: usize, natural: bool) -> RgbImage {
    let mut img = RgbImage::new(width, height);
    for y in 0..height {
        for x in 0..width {
            let (fx, fy) = (x as f64, y as f64);
            let shade = 0.55 + 0.35 * (fx * 0.03).sin() * (fy * 0.021).cos();
            let tex = 0.85 + 0.3 * value_noise(fx, fy, 3.0, 7);
            let region = ((fx / 37.0).floor() as i64 + (fy / 29.0).floor() as i64).rem_euclid(4);
            let colour = if natural {
                let level = [0.35, 0.6, 0.8, 1.0][region as usize];
                [
                    230.0 * level * (1.0 + 0.15 * (fx / 60.0).sin()),
                    220.0 * level,
                    200.0 * level * (1.0 + 0.15 * (fy / 45.0).cos()),
                ]
            } else {
                match region {
                    0 => [230.0, 90.0, 60.0],
                    1 => [70.0, 200.0, 90.0],
                    2 => [60.0, 110.0, 230.0],
                    _ => [210.0, 210.0, 200.0],
                }
            };
            for c in 0..3 {
                img.data[3 * (y * width + x) + c] =
                    (colour[c] * shade * tex).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    img
}

#[test]
fn demosaic_psnr_bilinear_vs_malvar() {
    for natural in [true, false] {
        let truth = demosaic_test_image(320, 240, natural);
        let mut psnr = Vec::new();
        for pattern in [BayerPattern::Bggr, BayerPattern::Rggb] {
            let raw = image::mosaic(&truth, pattern);
            let mut rgb = RgbImage::default();
            for method in [Demosaic::Bilinear, Demosaic::MalvarHeCutler] {
                image::demosaic_into(&raw, pattern, method, &mut rgb).unwrap();
                // Every pixel keeps its own sample exactly.
                for y in 0..truth.height {
                    for x in 0..truth.width {
                        let c = pattern.channel(x, y);
                        assert_eq!(rgb.get(x, y)[c], truth.get(x, y)[c]);
                    }
                }
                let p = image::psnr_db(&truth, &rgb, 2);
                eprintln!(
                    "demosaic {} image, {pattern:?} {method:?}: PSNR {p:.2} dB",
                    if natural { "natural" } else { "chroma-edge" }
                );
                psnr.push(p);
            }
        }
        assert!(psnr.iter().all(|p| *p > 28.0), "{psnr:?}");
        if natural {
            // Malvar-He-Cutler must measurably improve on bilinear where channels correlate.
            assert!(psnr[1] > psnr[0] + 1.0, "{psnr:?}");
            assert!(psnr[3] > psnr[2] + 1.0, "{psnr:?}");
        }
    }
}

#[test]
fn real_pair_road_is_the_calibrated_ground_plane() {
    let Some(root) = data_dir("real_pair_road_is_the_calibrated_ground_plane") else {
        return;
    };
    let dir = root.join("ucsd/stereo_sample");
    let left = image::load_gray_png(&dir.join("image_left.png")).unwrap();
    let right = image::load_gray_png(&dir.join("image_right.png")).unwrap();
    let calib = StereoCalibration::ucsd();
    let options = StereoOptions::default();
    let mut pipeline = StereoPipeline::new(&calib, &options).unwrap();
    pipeline.process_raw_pair(&left, &right).unwrap();
    let geometry = *pipeline.geometry();
    let disparity = pipeline.disparity();
    // The road fills the lower part of the image (rows 380..560: 4-12 m ahead).
    let mut points = Vec::new();
    for v in 380..disparity.height {
        for u in 0..disparity.width {
            if let Some(d) = disparity.get(u, v).filter(|d| *d > 1.0) {
                let p = geometry.point_rectified(u as f64, v as f64, d as f64);
                points.push(geometry.body_from_rectified.transform_point(&p));
            }
        }
    }
    assert!(
        points.len() > 20_000,
        "only {} matched road pixels",
        points.len()
    );
    let fit = fit_plane_ransac(&points, 0.05, 500, 7).unwrap();
    let inlier_fraction = fit.inliers as f64 / points.len() as f64;
    let height_at_centroid = fit.z_at(fit.centroid.x, fit.centroid.y);
    let height_below_camera = fit.z_at(
        calib.body_from_camera.translation.x,
        calib.body_from_camera.translation.y,
    );
    eprintln!(
        "real pair road plane: {} points, inliers {:.1} %, height {:.3} m at the inliers' centroid \
         (x {:.1} m), {:.3} m below the camera, tilt {:.2} deg, rms {:.3} m",
        points.len(),
        100.0 * inlier_fraction,
        height_at_centroid,
        fit.centroid.x,
        height_below_camera,
        fit.tilt_rad().to_degrees(),
        fit.rms_m
    );
    // The calibration puts the camera 1.584 m above body z = 0, the road.
    assert!(height_at_centroid.abs() < 0.10, "{fit:?}");
    assert!(height_below_camera.abs() < 0.10, "{fit:?}");
    assert!(fit.tilt_rad().to_degrees() < 1.5, "{fit:?}");
    assert!(fit.rms_m < 0.035, "{fit:?}");
    assert!(inlier_fraction > 0.4, "{inlier_fraction}");

    // Lane markings: bright road points, fitted by lines along the driving direction.
    let colours: Vec<[u8; 3]> = {
        let img = pipeline.rectified_left();
        let mut c = Vec::new();
        for v in 380..disparity.height {
            for u in 0..disparity.width {
                if disparity.get(u, v).filter(|d| *d > 1.0).is_some() {
                    c.push(img.get(u, v));
                }
            }
        }
        c
    };
    // Markings are paint: at least twice as bright as the median road point.
    let luma = |c: &[u8; 3]| 0.299 * c[0] as f64 + 0.587 * c[1] as f64 + 0.114 * c[2] as f64;
    let mut road_luma: Vec<f64> = points
        .iter()
        .zip(&colours)
        .filter(|(p, _)| fit.distance_m(p).abs() < 0.05)
        .map(|(_, c)| luma(c))
        .collect();
    road_luma.sort_by(f64::total_cmp);
    let threshold = 2.0 * percentile(&road_luma, 0.5);
    let bright: Vec<Vector3<f64>> = points
        .iter()
        .zip(&colours)
        .filter(|(p, c)| fit.distance_m(p).abs() < 0.05 && luma(c) > threshold)
        .map(|(p, _)| *p)
        .collect();
    eprintln!(
        "lane marking candidates: {} road points brighter than {threshold:.0}",
        bright.len()
    );
    let lines = fit_lane_lines(&bright, 2);
    for (i, l) in lines.iter().enumerate() {
        eprintln!(
            "lane line {i}: {} points, y = {:.3} m at x = 6 m, heading {:.2} deg, length {:.1} m, rms {:.3} m",
            l.count,
            l.y_at(6.0),
            l.heading_rad.to_degrees(),
            l.length_m,
            l.rms_m
        );
    }
    assert!(!lines.is_empty(), "no lane marking found");
    // The longest marking: a straight line over metres, not a curve.
    let l = &lines[0];
    assert!(l.length_m > 4.0, "{l:?}");
    assert!(l.rms_m < 0.05, "{l:?}");
    assert!(l.count > 300, "{l:?}");
}

/// A line in the ground plane `y = y0 + tan(heading) x` fitted to marking points.
#[derive(Debug)]
struct LaneLine {
    y0_m: f64,
    heading_rad: f64,
    count: usize,
    rms_m: f64,
    length_m: f64,
}

impl LaneLine {
    fn y_at(&self, x: f64) -> f64 {
        self.y0_m + self.heading_rad.tan() * x
    }
}

/// Greedy RANSAC lines (within 20 deg of the x axis, 5 cm inlier band), best first.
fn fit_lane_lines(points: &[Vector3<f64>], max_lines: usize) -> Vec<LaneLine> {
    let mut remaining: Vec<Vector3<f64>> = points.to_vec();
    let mut lines = Vec::new();
    for k in 0..max_lines {
        if remaining.len() < 50 {
            break;
        }
        let mut best: Option<(usize, f64, f64)> = None;
        // Deterministic sample pairs.
        for s in 0..2000u64 {
            let i = (hash01(s as i64, k as i64, 11) * remaining.len() as f64) as usize;
            let j = (hash01(s as i64, k as i64, 12) * remaining.len() as f64) as usize;
            let (a, b) = (remaining[i], remaining[j]);
            if (b.x - a.x).abs() < 1.0 {
                continue;
            }
            let slope = (b.y - a.y) / (b.x - a.x);
            if slope.atan().abs() > 20f64.to_radians() {
                continue;
            }
            let y0 = a.y - slope * a.x;
            let n = remaining
                .iter()
                .filter(|p| (p.y - y0 - slope * p.x).abs() < 0.05)
                .count();
            if best.is_none_or(|(bn, _, _)| n > bn) {
                best = Some((n, y0, slope));
            }
        }
        let Some((_, y0, slope)) = best else { break };
        let (inliers, rest): (Vec<&Vector3<f64>>, Vec<&Vector3<f64>>) = remaining
            .iter()
            .partition(|p| (p.y - y0 - slope * p.x).abs() < 0.05);
        // Least squares y = a + b x on the inliers.
        let n = inliers.len() as f64;
        let (sx, sy) = inliers
            .iter()
            .fold((0.0, 0.0), |(sx, sy), p| (sx + p.x, sy + p.y));
        let (mx, my) = (sx / n, sy / n);
        let (sxx, sxy) = inliers.iter().fold((0.0, 0.0), |(a, b), p| {
            (a + (p.x - mx).powi(2), b + (p.x - mx) * (p.y - my))
        });
        let b = sxy / sxx;
        let a = my - b * mx;
        let rms = (inliers
            .iter()
            .map(|p| (p.y - a - b * p.x).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        let xs: Vec<f64> = inliers.iter().map(|p| p.x).collect();
        let length = xs.iter().cloned().fold(f64::MIN, f64::max)
            - xs.iter().cloned().fold(f64::MAX, f64::min);
        lines.push(LaneLine {
            y0_m: a,
            heading_rad: b.atan(),
            count: inliers.len(),
            rms_m: rms,
            length_m: length,
        });
        remaining = rest.into_iter().copied().collect();
    }
    lines
}

#[test]
fn rendered_ground_disparity_and_texture() {
    let calib = StereoCalibration::ucsd();
    let world_from_body = Pose2::new(2.0, -1.0, 0.3);
    let layout_from_world = world_from_body.inverse();
    let tex = |x: f64, y: f64| ground_texture(&layout_from_world, x, y);
    let (left, right) = render_ground_pair(
        &calib,
        &world_from_body,
        &tex,
        [170.0, 190.0, 215.0],
        3,
        BayerPattern::UCSD,
    )
    .unwrap();
    // Block matching (the default) and semi-global matching, measured on the same pair.
    let sgm = StereoOptions {
        matcher: MatcherOptions {
            window_radius: 2,
            aggregation: Aggregation::Sgm,
            ..MatcherOptions::default()
        },
        ..StereoOptions::default()
    };
    for options in [StereoOptions::default(), sgm] {
        let name = format!(
            "{:?} r={}",
            options.matcher.aggregation, options.matcher.window_radius
        );
        let mut pipeline = StereoPipeline::new(&calib, &options).unwrap();
        pipeline.process_raw_pair(&left, &right).unwrap();

        // Disparity against the exact one, where the ground is within the search range.
        let truth = ground_disparity(pipeline.geometry(), &world_from_body);
        let disparity = pipeline.disparity();
        if let Some(dir) = std::env::var_os("PFSLAM_STEREO_DEBUG") {
            let dir = std::path::PathBuf::from(dir);
            let l = pipeline.rectified_left();
            let r = pipeline.rectified_right();
            std::fs::write(dir.join("syn_left.png"), image::encode_rgb_png(l).unwrap()).unwrap();
            std::fs::write(dir.join("syn_right.png"), image::encode_rgb_png(r).unwrap()).unwrap();
            let mut vis = RgbImage::new(l.width, l.height);
            for i in 0..truth.len() {
                let d = disparity.data[i];
                vis.data[3 * i] = if d >= 0.0 {
                    (2.0 * d).min(255.0) as u8
                } else {
                    0
                };
                vis.data[3 * i + 1] = if truth[i].is_finite() {
                    (2.0 * truth[i]).min(255.0) as u8
                } else {
                    0
                };
            }
            std::fs::write(
                dir.join("syn_disp.png"),
                image::encode_rgb_png(&vis).unwrap(),
            )
            .unwrap();
        }
        DisparityStats::measure(&truth, disparity, &options)
            .check(&format!("rendered ground ({name})"));

        // Texture map against the true texture, per 10 cm cell, 6-15 m ahead, 3.5 m either side.
        let mut map = TextureMap::new(MapLimits::new(0.1, 0.0, 0.0));
        let added = pipeline.accumulate(&world_from_body, &mut map);
        assert!(added > 10_000, "{added}");
        let (mut cells, mut observed, mut err_sum) = (0usize, 0usize, 0.0f64);
        let mut worst = 0.0f64;
        for ix in -200..400 {
            for iy in -300..300 {
                let (cx, cy) = map.limits().cell_centre(Cell::new(ix, iy));
                let (bx, by) = layout_from_world.transform_point(cx, cy);
                if !(6.0..15.0).contains(&bx) || by.abs() > 3.5 {
                    continue;
                }
                cells += 1;
                let Some(c) = map.get(Cell::new(ix, iy)) else {
                    continue;
                };
                observed += 1;
                // The cell's true mean colour (6x6 samples).
                let mut t = [0.0; 3];
                for j in 0..6 {
                    for i in 0..6 {
                        let s = tex(
                            (ix as f64 + (i as f64 + 0.5) / 6.0) * 0.1,
                            (iy as f64 + (j as f64 + 0.5) / 6.0) * 0.1,
                        );
                        for k in 0..3 {
                            t[k] += s[k] / 36.0;
                        }
                    }
                }
                let e = (0..3).map(|k| (c.mean[k] - t[k]).abs()).sum::<f64>() / 3.0;
                worst = worst.max(e);
                err_sum += e;
            }
        }
        let coverage = observed as f64 / cells as f64;
        let mean_error = err_sum / observed as f64;
        eprintln!(
            "texture map ({name}): {cells} cells in the region, coverage {:.1} %, mean |colour error| {mean_error:.2} \
             (0-255 scale), worst cell {worst:.1}",
            100.0 * coverage
        );
        assert!(coverage > 0.9, "coverage {coverage}");
        assert!(mean_error < 10.0, "mean colour error {mean_error}");
    }
}

#[test]
fn rgbd_frame_colours_the_ground() {
    // A registered RGB-D camera 1 m above the ground, pitched 30 deg down, on a rotated body.
    let k = PinholeIntrinsics {
        width: 160,
        height: 120,
        fx_px: 120.0,
        fy_px: 120.0,
        cx_px: 80.0,
        cy_px: 60.0,
    };
    let camera = RgbdCamera {
        depth: k,
        colour: k,
        colour_from_depth: Rigid3::IDENTITY,
    };
    let pitch = 30f64.to_radians();
    // Camera axes in the body: z forward-down, x right (-y body), y down-ish.
    let fwd = Vector3::new(pitch.cos(), 0.0, -pitch.sin());
    let right = Vector3::new(0.0, -1.0, 0.0);
    let down = fwd.cross(&right);
    let body_from_depth = Rigid3 {
        rotation: nalgebra::Matrix3::from_columns(&[right, down, fwd]),
        translation: Vector3::new(0.2, 0.0, 1.0),
    };
    let world_from_body = Pose2::new(1.0, 2.0, -0.7);
    // Ground colour: red for world x < 3, else blue; depth of the ground plane per pixel.
    let world_from_depth = Rigid3::from_pose2(&world_from_body).compose(&body_from_depth);
    let mut depth = vec![0f32; k.width * k.height];
    let mut colour = RgbImage::new(k.width, k.height);
    for v in 0..k.height {
        for u in 0..k.width {
            let ray = k.ray(u as f64, v as f64);
            let dir = world_from_depth.rotation * ray;
            if dir.z >= -1e-6 {
                continue;
            }
            let s = -world_from_depth.translation.z / dir.z;
            let p = world_from_depth.translation + s * dir;
            depth[v * k.width + u] = s as f32; // ray has z = 1, so s is the depth
            let c = if p.x < 3.0 {
                [200, 30, 30]
            } else {
                [30, 30, 200]
            };
            let i = 3 * (v * k.width + u);
            colour.data[i..i + 3].copy_from_slice(&c);
        }
    }
    let options = StereoOptions::default();
    let mut map = TextureMap::new(MapLimits::new(0.1, 0.0, 0.0));
    let mut points = Vec::new();
    let frame = RgbdFrame {
        depth_m: &depth,
        colour: &colour,
        camera: &camera,
        body_from_depth: &body_from_depth,
        world_from_body: &world_from_body,
    };
    let added = accumulate_rgbd(&frame, &options, &mut points, &mut map);
    assert!(added > 5000, "{added}");
    // Every point lies on the ground and every cell has the colour of its side.
    assert!(points.iter().all(|p| p.p_m.z.abs() < 1e-6));
    let mut wrong = 0;
    for (&cell, c) in &map.cells {
        let (x, _) = map.limits().cell_centre(cell);
        if (x - 3.0).abs() < 0.1 {
            continue;
        }
        let expect = if x < 3.0 {
            [200, 30, 30]
        } else {
            [30, 30, 200]
        };
        if c.rgb8() != expect {
            wrong += 1;
        }
    }
    assert_eq!(wrong, 0);
    assert!(map.cells.len() > 200, "{}", map.cells.len());
}

#[test]
fn rectification_tables_invert_the_projection() {
    use pfslam_stereo::rectify::DistortedCamera;
    let calib = StereoCalibration::ucsd();
    let rect = pfslam_stereo::StereoRectifier::new(&calib).unwrap();
    let k = rect.geometry.intrinsics;
    // The baseline implied by P_right agrees with stereo_param.txt.
    let p = &calib.right.projection;
    assert!((-p[3] / p[0] - calib.baseline_m).abs() < 1e-4);
    for (info, table) in [(&calib.left, &rect.left), (&calib.right, &rect.right)] {
        let cam = DistortedCamera::from_info(info).unwrap();
        let r = nalgebra::Matrix3::from_row_slice(&info.rectification);
        let mut worst = 0.0f64;
        for v in (40..520).step_by(37) {
            for u in (60..1220).step_by(53) {
                let i = v * k.width + u;
                let (su, sv) = (table.map_x[i] as f64, table.map_y[i] as f64);
                assert!(su.is_finite() && sv.is_finite(), "({u},{v}) outside");
                // Raw pixel -> undistorted ray -> rectified frame -> P: back to (u, v).
                let ray = r * cam.unproject(su, sv);
                let (pu, pv) = k.project(&ray).unwrap();
                worst = worst.max((pu - u as f64).abs().max((pv - v as f64).abs()));
            }
        }
        // f32 tables: a few thousandths of a pixel.
        assert!(worst < 5e-3, "round trip error {worst} px");
    }
}

#[test]
fn plane_fit_rejects_outliers() {
    // z = 0.02 x - 0.01 y + 0.5 with 1 cm noise, plus 30 % outliers.
    let mut pts = Vec::new();
    for i in 0..2000 {
        let x = hash01(i, 0, 21) * 10.0;
        let y = hash01(i, 1, 21) * 6.0 - 3.0;
        let z = if i % 10 < 3 {
            hash01(i, 2, 21) * 3.0 - 1.0
        } else {
            0.02 * x - 0.01 * y + 0.5 + (hash01(i, 3, 21) - 0.5) * 0.02
        };
        pts.push(Vector3::new(x, y, z));
    }
    let fit = fit_plane_ransac(&pts, 0.03, 300, 3).unwrap();
    assert!((fit.z_at(0.0, 0.0) - 0.5).abs() < 0.01, "{fit:?}");
    assert!((fit.z_at(10.0, 0.0) - 0.7).abs() < 0.01, "{fit:?}");
    assert!(fit.inliers >= 1400 && fit.inliers < 1500, "{}", fit.inliers);
    assert!(fit.rms_m < 0.01);
    assert!((fit.tilt_rad() - (0.02f64.hypot(0.01)).atan()).abs() < 0.003);
}

#[test]
fn texture_map_running_mean_and_raster_orientation() {
    use pfslam_stereo::ColouredPoint;
    let mut map = TextureMap::new(MapLimits::new(0.5, -1.0, -1.0));
    let pt = |x: f64, y: f64, z: f64, rgb: [u8; 3]| ColouredPoint {
        p_m: Vector3::new(x, y, z),
        rgb,
    };
    let kept = map.add_ground_points(
        &[
            pt(0.1, 0.1, 0.0, [10, 20, 30]),
            pt(0.2, 0.3, 0.05, [30, 40, 50]),
            pt(0.2, 0.3, 2.0, [255, 255, 255]), // above the ground window
            pt(-0.9, 1.4, 0.0, [200, 0, 0]),
        ],
        -0.3,
        0.3,
    );
    assert_eq!(kept, 3);
    let c = map.get(map.limits().cell_of(0.1, 0.1)).unwrap();
    assert_eq!((c.count, c.rgb8()), (2, [20, 30, 40]));
    let rect = map.bounds().unwrap();
    // Cells (2, 2) and (0, 4): 3 columns, 3 rows.
    assert_eq!((rect.width(), rect.height()), (3, 3));
    let (rgb, count) = map.rasterize(&rect);
    // Row 0 is the top (largest y): the red cell at x -0.9, y 1.4 is at column 0 of row 0.
    assert_eq!(&rgb[0..3], &[200.0, 0.0, 0.0]);
    assert_eq!(count[0], 1.0);
    // The grey cell (x 0.1, y 0.1) is column 2 of the bottom row; empty cells are NaN.
    assert_eq!(count[2 * 3 + 2], 2.0);
    assert_eq!(&rgb[3 * 8..3 * 8 + 3], &[20.0, 30.0, 40.0]);
    assert!(rgb[3].is_nan());
}

/// The real-data directory (`$PFSLAM_DATA` or `shared/data` beside the workspace root), or
/// `None` after printing a skip notice naming the test.
fn data_dir(test: &str) -> Option<std::path::PathBuf> {
    let d = pfslam::files::data_root(env!("CARGO_MANIFEST_DIR"));
    if d.is_none() {
        eprintln!("SKIP {test}: real data not found (set PFSLAM_DATA or provide ../shared/data)");
    }
    d
}
