//! The simulator's outputs written as datasets with `pfslam-io`'s writers: a simulated car
//! recording in the car's layout ([`write_car_sim`], with its rendered stereo pairs), a
//! simulated humanoid recording in the humanoid's layout ([`write_humanoid_sim`]), and beside
//! each its ground truth:
//! `ground_truth.tum`, the true maps (PNG and map_server pairs), `world.world`, `sim.toml` and,
//! for the humanoid, `beam_labels.csv` (header `timestamp_ns,labels`; per scan one string of N
//! digits, one per beam: `0` no return, `1` obstacle, `2` floor).

use crate::{
    CarSimOutput, HumanoidSimOutput, ScanSurfaceTruth, SimError, SimOptions, TrueMap, sim_toml,
};
use pfslam::geometry::StampedPose2;
use pfslam::map::CellState;
use pfslam_io::humanoid::write_humanoid_dataset;
use pfslam_io::map_files::write_map_server;
use pfslam_io::tum::write_tum;
use pfslam_io::ucsd::{STEREO_LEFT_DIR, STEREO_RIGHT_DIR, write_car_dataset};
use pfslam_io::{IoError, parse_i64, write_atomic, write_bytes_atomic};
use std::path::Path;

/// Ground-truth beam label file name.
pub const BEAM_LABELS_CSV: &str = "beam_labels.csv";

/// Writes what every simulated recording has: `ground_truth.tum`, the band true map as
/// `<true_map_stem>.{png,pgm,yaml}`, `world.world` and `sim.toml`.
fn write_truth(
    dir: &Path,
    ground_truth: &[StampedPose2],
    true_map: &TrueMap,
    true_map_stem: &str,
    world_text: &str,
    options: &SimOptions,
) -> Result<(), SimError> {
    write_tum(&dir.join("ground_truth.tum"), ground_truth)?;
    write_true_map(true_map, dir, true_map_stem)?;
    write_bytes_atomic(&dir.join("world.world"), world_text.as_bytes())?;
    write_bytes_atomic(&dir.join("sim.toml"), sim_toml(options)?.as_bytes())?;
    Ok(())
}

/// Writes a simulated car recording into `dir`: the dataset in the car's layout, plus
/// `ground_truth.tum`, the scan-surface truth `true_map.{png,pgm,yaml}` +
/// `true_map_visible.{pgm,yaml}`, the fixed-band `true_map_band.{png,pgm,yaml}`,
/// `world.world` and `sim.toml`; and the stereo
/// pairs, rendered here (see [`write_stereo_pairs`]).
pub fn write_car_sim(dir: &Path, out: &CarSimOutput) -> Result<(), SimError> {
    std::fs::create_dir_all(dir).map_err(|e| IoError::io(dir, e))?;
    write_car_dataset(dir, &out.dataset)?;
    write_stereo_pairs(dir, out)?;
    write_truth(
        dir,
        &out.ground_truth,
        &out.true_map,
        "true_map_band",
        &out.world_text,
        &out.options,
    )?;
    write_scan_truth(&out.scan_truth, dir, "true_map")?;
    Ok(())
}

/// Renders the stereo pair at each of `out.stereo_poses` (the rig of the dataset's calibration,
/// the built-in one when absent) and writes them as raw Bayer BG PNGs into
/// `dir/stereo_images/stereo_{left,right}/<stamp_ns>.png`. Earlier `<stamp_ns>.png` files in
/// those folders are removed first (even with stereo off), so the folder always matches this
/// recording. Each frame is rendered in parallel over rows, pixel by pixel, so the output
/// does not depend on the thread count.
pub fn write_stereo_pairs(dir: &Path, out: &CarSimOutput) -> Result<(), SimError> {
    use crate::WorldScene;
    use pfslam_stereo::image::{BayerPattern, encode_gray_png};
    for sub in [STEREO_LEFT_DIR, STEREO_RIGHT_DIR] {
        remove_stamp_pngs(&dir.join(sub))?;
    }
    if out.stereo_poses.is_empty() {
        return Ok(());
    }
    let calib = out
        .dataset
        .calibration
        .stereo
        .clone()
        .unwrap_or_else(pfslam::sensors::StereoCalibration::ucsd);
    let (left_dir, right_dir) = (dir.join(STEREO_LEFT_DIR), dir.join(STEREO_RIGHT_DIR));
    for d in [&left_dir, &right_dir] {
        std::fs::create_dir_all(d).map_err(|e| IoError::io(d, e))?;
    }
    // Sky beyond 200 m: nothing in a campus-scale world is farther and still worth a ray.
    let scene = WorldScene::new(&out.world, 200.0);
    let supersample = out.options.car.stereo_supersample;
    for p in &out.stereo_poses {
        let (left, right) = scene.render_pair(&calib, &p.pose, supersample, BayerPattern::UCSD)?;
        let name = format!("{}.png", p.stamp_ns);
        write_bytes_atomic(&left_dir.join(&name), &encode_gray_png(&left)?)?;
        write_bytes_atomic(&right_dir.join(&name), &encode_gray_png(&right)?)?;
    }
    Ok(())
}

/// Removes the `<digits>.png` files of `dir` (a missing folder is fine).
fn remove_stamp_pngs(dir: &Path) -> Result<(), SimError> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(IoError::io(dir, e).into()),
    };
    for entry in entries {
        let path = entry.map_err(|e| IoError::io(dir, e))?.path();
        let is_stamp_png = path.extension().and_then(|e| e.to_str()) == Some("png")
            && path
                .file_stem()
                .and_then(|s| s.to_str())
                .is_some_and(|s| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()));
        if is_stamp_png {
            std::fs::remove_file(&path).map_err(|e| IoError::io(&path, e))?;
        }
    }
    Ok(())
}

/// An 8-bit grey image as PNG bytes; `path` names the file in errors.
fn encode_l8_png(path: &Path, px: &[u8], width: usize, height: usize) -> Result<Vec<u8>, IoError> {
    use image::ImageEncoder;
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(
            px,
            width as u32,
            height as u32,
            image::ExtendedColorType::L8,
        )
        .map_err(|e| IoError::io(path, std::io::Error::other(e.to_string())))?;
    Ok(png)
}

/// Writes the true map as `<stem>.png`, and `<stem>.pgm` + `<stem>.yaml` (map_server pair, via
/// [`write_map_server`]) into `dir`.
pub fn write_true_map(map: &TrueMap, dir: &Path, stem: &str) -> Result<(), IoError> {
    let px = map.image_rows();
    let png_path = dir.join(format!("{stem}.png"));
    let png = encode_l8_png(&png_path, &px, map.width, map.height)?;
    write_bytes_atomic(&png_path, &png)?;
    write_map_server(&map.to_binary_map(), &dir.join(format!("{stem}.yaml")))?;
    Ok(())
}

/// Writes the scan-surface truth as `<stem>.png` (occupancy: black occupied, white free, grey
/// unknown), `<stem>.pgm` + `<stem>.yaml` (occupancy) and `<stem>_visible.pgm` + `.yaml` into
/// `dir`.
pub fn write_scan_truth(truth: &ScanSurfaceTruth, dir: &Path, stem: &str) -> Result<(), IoError> {
    write_map_server(&truth.occupancy, &dir.join(format!("{stem}.yaml")))?;
    write_map_server(&truth.visible, &dir.join(format!("{stem}_visible.yaml")))?;
    let m = &truth.occupancy;
    let mut px = Vec::with_capacity(m.width * m.height);
    for j in (0..m.height).rev() {
        px.extend(
            m.cells[j * m.width..(j + 1) * m.width]
                .iter()
                .map(|s| match s {
                    CellState::Occupied => 0u8,
                    CellState::Free => 254,
                    CellState::Unknown => 205,
                }),
        );
    }
    let png_path = dir.join(format!("{stem}.png"));
    let png = encode_l8_png(&png_path, &px, m.width, m.height)?;
    write_bytes_atomic(&png_path, &png)
}

/// Writes the humanoid dataset plus `ground_truth.tum`, `beam_labels.csv`,
/// `true_map.{png,pgm,yaml}`, `world.world` and `sim.toml` into `dir`.
pub fn write_humanoid_sim(dir: &Path, out: &HumanoidSimOutput) -> Result<(), SimError> {
    write_humanoid_dataset(dir, &out.dataset)?;
    write_truth(
        dir,
        &out.ground_truth,
        &out.true_map,
        "true_map",
        &out.world_text,
        &out.options,
    )?;
    let nb = out.dataset.lidar.beam_count;
    write_atomic(&dir.join(BEAM_LABELS_CSV), |w| {
        writeln!(w, "timestamp_ns,labels")?;
        let mut line = Vec::with_capacity(nb + 1);
        for (i, stamp) in out.dataset.lidar.stamps_ns.iter().enumerate() {
            line.clear();
            line.extend(
                out.beam_labels[i * nb..(i + 1) * nb]
                    .iter()
                    .map(|&l| b'0' + l),
            );
            line.push(b'\n');
            write!(w, "{stamp},")?;
            w.write_all(&line)?;
        }
        Ok(())
    })?;
    Ok(())
}

/// Reads `beam_labels.csv`: the stamps and the flat labels (`beam_count` per scan).
pub fn read_beam_labels(path: &Path, beam_count: usize) -> Result<(Vec<i64>, Vec<u8>), SimError> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))?;
    let mut lines = text.lines().enumerate();
    if lines.next().map(|(_, l)| l.trim()) != Some("timestamp_ns,labels") {
        return Err(IoError::parse(path, 1, "expected the header \"timestamp_ns,labels\"").into());
    }
    let (mut stamps, mut labels) = (Vec::new(), Vec::new());
    for (idx, line) in lines {
        let ln = idx + 1;
        let (t, l) = line
            .trim()
            .split_once(',')
            .ok_or_else(|| IoError::parse(path, ln, "expected timestamp_ns,labels"))?;
        stamps.push(parse_i64(path, ln, "timestamp_ns", t)?);
        if l.len() != beam_count || !l.bytes().all(|b| (b'0'..=b'2').contains(&b)) {
            return Err(
                IoError::parse(path, ln, format!("expected {beam_count} labels in 0..=2")).into(),
            );
        }
        labels.extend(l.bytes().map(|b| b - b'0'));
    }
    Ok((stamps, labels))
}

#[cfg(test)]
mod tests {
    use super::*;
    use pfslam_io::map_files::read_map_server;

    #[test]
    fn true_map_reads_back_as_map_server() {
        let w = crate::truth::tests::three_prisms();
        let m = TrueMap::rasterize(&w, 0.1, [1.0, 4.0], 1.0);
        let dir = tempfile::tempdir().unwrap();
        write_true_map(&m, dir.path(), "true_map").unwrap();
        let back = read_map_server(&dir.path().join("true_map.yaml")).unwrap();
        assert_eq!(back.width, m.width);
        assert_eq!(back.cells, m.to_binary_map().cells);
        assert_eq!(back.state_at(5.0, 5.0), CellState::Occupied);
        assert!(dir.path().join("true_map.png").is_file());
    }
}
