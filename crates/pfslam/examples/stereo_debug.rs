use pfslam::stereo::*;
use std::path::Path;
fn main() {
    let dir = Path::new("/work/shared/data/ucsd/stereo_sample");
    let l = image::load_gray_png(&dir.join("image_left.png")).unwrap();
    let r = image::load_gray_png(&dir.join("image_right.png")).unwrap();
    let calib = pfslam::sensors::StereoCalibration::ucsd();
    for dm in [Demosaic::Bilinear, Demosaic::MalvarHeCutler] {
        let opts = StereoOptions {
            demosaic: dm,
            ..StereoOptions::default()
        };
        let mut pipe = StereoPipeline::new(&calib, &opts).unwrap();
        pipe.process_raw_pair(&l, &r).unwrap();
        let g = *pipe.geometry();
        let d = pipe.disparity();
        let mut pts = Vec::new();
        for v in 380..560 {
            for u in 0..1280 {
                if let Some(dd) = d.get(u, v) {
                    if dd > 1.0 {
                        pts.push(
                            g.body_from_rectified
                                .transform_point(&g.point_rectified(u as f64, v as f64, dd as f64)),
                        );
                    }
                }
            }
        }
        let fit = fit_plane_ransac(&pts, 0.05, 500, 7).unwrap();
        println!(
            "{dm:?}: valid {:.3}, lower {} pts, inliers {} ({:.1}%), rms {:.4}, tilt {:.2}",
            d.valid_fraction(),
            pts.len(),
            fit.inliers,
            100.0 * fit.inliers as f64 / pts.len() as f64,
            fit.rms_m,
            fit.tilt_rad().to_degrees()
        );
    }
}
