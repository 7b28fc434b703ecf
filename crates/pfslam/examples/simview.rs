use pfslam::stereo::render::WorldScene;
use pfslam::stereo::*;
fn main() {
    let world = pfslam::sim::world::World::builtin("campus").unwrap();
    let scene = WorldScene::new(&world, 200.0);
    let calib = pfslam::sensors::StereoCalibration::ucsd();
    let (a, b) = (world.route[0], world.route[1]);
    let pose = pfslam::geometry::Pose2::new(a[0], a[1], (b[1] - a[1]).atan2(b[0] - a[0]));
    let (l, r) = scene
        .render_pair(&calib, &pose, 2, BayerPattern::UCSD)
        .unwrap();
    let mut p = StereoPipeline::new(&calib, &StereoOptions::default()).unwrap();
    p.process_raw_pair(&l, &r).unwrap();
    std::fs::write(
        "/tmp/sim_left.png",
        image::encode_rgb_png(p.rectified_left()).unwrap(),
    )
    .unwrap();
    let d = p.disparity();
    let mut vis = RgbImage::new(d.width, d.height);
    for i in 0..d.data.len() {
        let v = d.data[i];
        if v >= 0.0 {
            let g = (2.0 * v).min(255.0) as u8;
            vis.data[3 * i..3 * i + 3].copy_from_slice(&[g, g, g]);
        } else {
            vis.data[3 * i] = 80;
        }
    }
    std::fs::write("/tmp/sim_disp.png", image::encode_rgb_png(&vis).unwrap()).unwrap();
}
