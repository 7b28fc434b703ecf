//! Writing a car dataset in the course's layout.

use super::*;

/// Writes `encoder.csv` (no header, as the course's files).
pub fn write_encoder_csv(path: &Path, rows: &[EncoderSample]) -> Result<(), IoError> {
    write_atomic(path, |w| {
        for r in rows {
            writeln!(w, "{},{},{}", r.stamp_ns, r.left_count, r.right_count)?;
        }
        Ok(())
    })
}

/// Writes `fog.csv`; floats in shortest round-trip form, so reading gives the same bits.
pub fn write_fog_csv(path: &Path, rows: &[FogSample]) -> Result<(), IoError> {
    write_atomic(path, |w| {
        for r in rows {
            writeln!(
                w,
                "{},{},{},{}",
                r.stamp_ns, r.delta_roll_rad, r.delta_pitch_rad, r.delta_yaw_rad
            )?;
        }
        Ok(())
    })
}

/// Writes `lidar.csv`; `f32` ranges in shortest round-trip form.
pub fn write_lidar_csv(path: &Path, scans: &ScanSet) -> Result<(), IoError> {
    write_atomic(path, |w| {
        for i in 0..scans.len() {
            write!(w, "{}", scans.stamps_ns[i])?;
            for r in scans.ranges(i) {
                write!(w, ",{r}")?;
            }
            writeln!(w)?;
        }
        Ok(())
    })
}

/// Writes a dataset in the course's layout: the three CSVs and every calibration file
/// (camera YAML when `calibration.stereo` is `Some`). Stereo images are not written.
pub fn write_car_dataset(dir: &Path, ds: &CarDataset) -> Result<(), IoError> {
    write_car_calibration(&dir.join(PARAM_DIR), &ds.calibration)?;
    write_encoder_csv(&dir.join(ENCODER_CSV), &ds.encoder)?;
    write_fog_csv(&dir.join(FOG_CSV), &ds.fog)?;
    write_lidar_csv(&dir.join(LIDAR_CSV), &ds.lidar)
}
