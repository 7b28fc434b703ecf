//! Disparity of one 1280x560 pair (the car's camera): the matcher alone, and the whole chain
//! from raw Bayer frames (demosaic, rectify, match).

use criterion::{Criterion, criterion_group, criterion_main};
use pfslam::geometry::Pose2;
use pfslam::sensors::StereoCalibration;
use pfslam_stereo::disparity::compute_disparity;
use pfslam_stereo::image::BayerPattern;
use pfslam_stereo::render::render_ground_pair;
use pfslam_stereo::{DisparityMap, DisparityWorkspace, GrayImage, StereoOptions, StereoPipeline};
use std::hint::black_box;
use std::time::Duration;

/// A textured ground plane seen by the car's rig.
fn ground(x: f64, y: f64) -> [f64; 3] {
    let n = ((x * 37.0).sin() * (y * 23.0).cos() + (x * 11.0 + y * 7.0).sin()) * 0.25 + 0.5;
    let g = 50.0 + 150.0 * n;
    [g, g * 0.95, g * 0.9]
}

fn bench(c: &mut Criterion) {
    let calib = StereoCalibration::ucsd();
    let (left_raw, right_raw) = render_ground_pair(
        &calib,
        &Pose2::IDENTITY,
        &ground,
        [150.0; 3],
        1,
        BayerPattern::UCSD,
    )
    .expect("render");
    let options = StereoOptions::default();
    let mut pipeline = StereoPipeline::new(&calib, &options).expect("pipeline");
    pipeline
        .process_raw_pair(&left_raw, &right_raw)
        .expect("pair");
    let (mut left, mut right) = (GrayImage::default(), GrayImage::default());
    pipeline.rectified_left().to_gray_into(&mut left);
    pipeline.rectified_right().to_gray_into(&mut right);

    let mut group = c.benchmark_group("disparity_1280x560");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(10));
    let mut ws = DisparityWorkspace::new();
    let mut out = DisparityMap::default();
    group.bench_function("census_block_matching_128", |b| {
        b.iter(|| {
            compute_disparity(
                black_box(&left),
                black_box(&right),
                &options.matcher,
                &mut ws,
                &mut out,
            )
            .expect("match")
        })
    });
    let sgm = pfslam_stereo::MatcherOptions {
        window_radius: 2,
        aggregation: pfslam_stereo::disparity::Aggregation::Sgm,
        ..options.matcher.clone()
    };
    group.bench_function("census_sgm5_128", |b| {
        b.iter(|| {
            compute_disparity(black_box(&left), black_box(&right), &sgm, &mut ws, &mut out)
                .expect("match")
        })
    });
    group.bench_function("raw_pair_demosaic_rectify_match", |b| {
        b.iter(|| {
            pipeline
                .process_raw_pair(black_box(&left_raw), black_box(&right_raw))
                .expect("pair")
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
