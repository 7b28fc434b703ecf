//! The simulated car's stereo pairs: written in the car's layout, deterministic, and
//! switching them on leaves every other stream unchanged.

use pfslam_io::ucsd::{STEREO_LEFT_DIR, STEREO_RIGHT_DIR, read_stereo_stamps};
use pfslam_sim::dataset::write_car_sim;
use pfslam_sim::{SimOptions, World, simulate_car};
use pfslam_stereo::image::load_gray_png;

#[test]
fn stereo_pairs_are_written_deterministically_and_leave_the_rest_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let world = World::builtin("campus").unwrap();
    let mut opts = SimOptions {
        duration_s: 2.0,
        seed: 9,
        ..SimOptions::default()
    };
    opts.car.stereo_rate_hz = 1.0;
    // Once on one thread, once on two: the images must not depend on the thread count.
    for (k, threads) in [("a", 1), ("b", 2)] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let out = simulate_car(&world, &opts).unwrap();
            write_car_sim(&dir.path().join(k), &out).unwrap();
        });
    }
    super::sim::assert_same_files(&dir.path().join("a"), &dir.path().join("b"));

    let on = simulate_car(&world, &opts).unwrap();
    let a = dir.path().join("a");
    let stamps = read_stereo_stamps(&a).unwrap();
    assert_eq!(stamps.len(), 2);
    assert_eq!(stamps, on.dataset.stereo_stamps_ns);
    assert_eq!(on.stereo_poses.len(), 2);
    for s in &stamps {
        let name = format!("{s}.png");
        let left = load_gray_png(&a.join(STEREO_LEFT_DIR).join(&name)).unwrap();
        let right = load_gray_png(&a.join(STEREO_RIGHT_DIR).join(&name)).unwrap();
        assert_eq!((left.width, left.height), (1280, 560));
        assert_eq!((right.width, right.height), (1280, 560));
        // Textured, not blank: many distinct grey levels, and the two views differ.
        let mut levels = [false; 256];
        for &v in &left.data {
            levels[v as usize] = true;
        }
        assert!(levels.iter().filter(|&&l| l).count() > 100);
        assert_ne!(left.data, right.data);
    }

    // Stereo off: identical sensor streams, and the old images are removed on rewrite.
    opts.car.stereo_rate_hz = 0.0;
    let off = simulate_car(&world, &opts).unwrap();
    assert!(off.stereo_poses.is_empty() && off.dataset.stereo_stamps_ns.is_empty());
    assert_eq!(off.dataset.lidar, on.dataset.lidar);
    assert_eq!(off.dataset.encoder, on.dataset.encoder);
    assert_eq!(off.dataset.fog, on.dataset.fog);
    assert_eq!(off.ground_truth, on.ground_truth);
    write_car_sim(&a, &off).unwrap();
    assert!(read_stereo_stamps(&a).unwrap().is_empty());

    opts.car.stereo_rate_hz = -1.0;
    assert!(opts.validate().is_err());
    opts.car.stereo_rate_hz = 1.0;
    opts.car.stereo_supersample = 0;
    assert!(opts.validate().is_err());
}
