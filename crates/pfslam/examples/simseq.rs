use pfslam::stereo::render::WorldScene;
use pfslam::stereo::*;
fn main() {
    let world = pfslam::sim::world::World::builtin("campus").unwrap();
    let scene = WorldScene::new(&world, 200.0);
    let calib = pfslam::sensors::StereoCalibration::ucsd();
    let traj = pfslam::io::tum::read_tum(std::path::Path::new("/tmp/stereo_sim/ground_truth.tum"))
        .unwrap();
    let dir = std::path::Path::new("/tmp/stereo_ds");
    std::fs::create_dir_all(dir.join("stereo_images/stereo_left")).unwrap();
    std::fs::create_dir_all(dir.join("stereo_images/stereo_right")).unwrap();
    let t0 = traj.poses[0].stamp_ns;
    for k in 0..25 {
        let stamp = t0 + k * 1_000_000_000;
        let Some(pose) = traj.pose_at(stamp) else {
            break;
        };
        let (l, r) = scene
            .render_pair(&calib, &pose, 1, BayerPattern::UCSD)
            .unwrap();
        std::fs::write(
            dir.join(format!("stereo_images/stereo_left/{stamp}.png")),
            image::encode_gray_png(&l).unwrap(),
        )
        .unwrap();
        std::fs::write(
            dir.join(format!("stereo_images/stereo_right/{stamp}.png")),
            image::encode_gray_png(&r).unwrap(),
        )
        .unwrap();
    }
}
