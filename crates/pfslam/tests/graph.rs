//! The pose-graph back end: the optimiser on synthetic loops (drift removed by a closure, a
//! wrong closure down-weighted by the robust kernel), the loop-closure matcher on a synthetic
//! world (known offset found, corridor rejected as ambiguous), and MIT-CSAIL end to end.

use pfslam::geometry::Pose2;
use pfslam::graph::optimize::{Edge, OptimizeOptions, PoseGraph};
use pfslam::graph::{GraphOptions, Verdict, verify_closure, verify_closure_in};
use pfslam::matching::point_field::{PointField, SearchWindow};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;

const SIDE: usize = 10;
const SIGMA_XY: f64 = 0.01;
const SIGMA_YAW: f64 = 0.1 * std::f64::consts::PI / 180.0;

/// A 10 m square, a node every metre, turning left at the corners.
fn square_truth() -> Vec<Pose2> {
    let mut poses = vec![Pose2::IDENTITY];
    for k in 1..4 * SIDE {
        let step = if k % SIDE == 0 {
            Pose2::new(1.0, 0.0, std::f64::consts::FRAC_PI_2)
        } else {
            Pose2::new(1.0, 0.0, 0.0)
        };
        let last = poses[k - 1];
        poses.push(last.compose(&step));
    }
    poses
}

/// Odometry edges with a yaw bias of 0.3 deg per step and Gaussian noise, the graph
/// initialised by chaining them (dead reckoning), plus one correct closure last -> first
/// (plain least squares: with odometry this stiff, a kernel would rather leave a 4 m drift
/// unclosed; the back end closes loops incrementally, before the drift grows).
fn drifting_square(seed: u64) -> (Vec<Pose2>, PoseGraph) {
    let truth = square_truth();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let nxy = Normal::new(0.0, SIGMA_XY).unwrap();
    let nyaw = Normal::new(0.0, SIGMA_YAW).unwrap();
    let bias = 0.3f64.to_radians();
    let mut g = PoseGraph {
        poses: vec![truth[0]],
        edges: Vec::new(),
    };
    for k in 1..truth.len() {
        let t = truth[k - 1].between(&truth[k]);
        let z = Pose2::new(
            t.x_m + nxy.sample(&mut rng),
            t.y_m + nxy.sample(&mut rng),
            t.yaw_rad + bias + nyaw.sample(&mut rng),
        );
        g.edges
            .push(Edge::with_sigmas(k - 1, k, z, SIGMA_XY, SIGMA_YAW, None));
        let last = g.poses[k - 1];
        g.poses.push(last.compose(&z));
    }
    let n = truth.len() - 1;
    g.edges.push(Edge::with_sigmas(
        0,
        n,
        truth[0].between(&truth[n]),
        SIGMA_XY,
        SIGMA_YAW,
        None,
    ));
    (truth, g)
}

fn max_error_m(a: &[Pose2], b: &[Pose2]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p.x_m - q.x_m).hypot(p.y_m - q.y_m))
        .fold(0.0, f64::max)
}

/// Three standard deviations of the worst node after closing the loop: the midpoint of a
/// Brownian bridge of N steps has sqrt(N / 4) steps of noise, yaw noise acting on a lever of
/// the half diagonal.
fn tolerance_m() -> f64 {
    let n = (4 * SIDE) as f64;
    let lever = SIDE as f64 / std::f64::consts::SQRT_2;
    3.0 * (n / 4.0).sqrt() * (SIGMA_XY + SIGMA_YAW * lever)
}

#[test]
fn square_loop_closure_removes_the_drift() {
    for seed in 1..=5 {
        let (truth, mut g) = drifting_square(seed);
        let before = max_error_m(&g.poses, &truth);
        assert!(before > 1.0, "the odometry should drift: {before}");
        let r = g.optimize(&OptimizeOptions::default());
        let after = max_error_m(&g.poses, &truth);
        assert!(r.final_cost < r.initial_cost);
        assert!(
            after < tolerance_m(),
            "seed {seed}: {after:.3} m after (tolerance {:.3}, before {before:.3})",
            tolerance_m()
        );
    }
}

#[test]
fn a_wrong_closure_is_down_weighted_by_the_kernel() {
    // The loop is closed and optimised first (as the back end does as soon as a closure
    // arrives); then a wrong closure comes.
    let (truth, mut g) = drifting_square(7);
    g.optimize(&OptimizeOptions::default());
    // Claims that node 5 (middle of the first side) and node 25 (middle of the third side,
    // 10 m away) are the same place.
    let wrong = Edge::with_sigmas(
        5,
        25,
        Pose2::new(0.0, 0.0, std::f64::consts::PI),
        SIGMA_XY,
        SIGMA_YAW,
        Some(3.0),
    );
    let mut robust = g.clone();
    robust.edges.push(wrong);
    robust.optimize(&OptimizeOptions {
        max_iterations: 50,
        ..OptimizeOptions::default()
    });
    let robust_err = max_error_m(&robust.poses, &truth);
    assert!(
        robust_err < tolerance_m(),
        "{robust_err:.3} m with the kernel"
    );
    // The wrong edge stands out (the back end drops edges above `loops.outlier_chi2`).
    let k = robust.edges.len() - 1;
    assert!(robust.edge_chi2(k) > GraphOptions::default().loops.outlier_chi2);
    // Without the kernel the same edge bends the square.
    let mut plain = g.clone();
    plain.edges.push(Edge {
        robust_width: None,
        ..wrong
    });
    plain.optimize(&OptimizeOptions {
        max_iterations: 50,
        ..OptimizeOptions::default()
    });
    let plain_err = max_error_m(&plain.poses, &truth);
    assert!(plain_err > 1.0, "{plain_err:.3} m without the kernel");
}

/// Points every 2 cm along the segments.
fn segments(segs: &[([f64; 2], [f64; 2])]) -> Vec<[f64; 2]> {
    let mut pts = Vec::new();
    for (a, b) in segs {
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let n = (len / 0.02).ceil() as usize;
        for k in 0..=n {
            let t = k as f64 / n as f64;
            pts.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
        }
    }
    pts
}

/// The world points within `range_m` of `pose`, in its frame, every `step`-th.
fn scan_from(world: &[[f64; 2]], pose: &Pose2, range_m: f64, step: usize) -> Vec<[f64; 2]> {
    let inv = pose.inverse();
    world
        .iter()
        .filter(|p| (p[0] - pose.x_m).hypot(p[1] - pose.y_m) < range_m)
        .step_by(step)
        .map(|p| {
            let (x, y) = inv.transform_point(p[0], p[1]);
            [x, y]
        })
        .collect()
}

fn field_for(world: &[[f64; 2]], lo: [f64; 2], hi: [f64; 2], opts: &GraphOptions) -> PointField {
    PointField::build(world, lo, hi, opts.resolution_m, opts.field_sigma_m, 5)
}

fn loop_window(opts: &GraphOptions) -> SearchWindow {
    SearchWindow {
        xy_m: opts.loops.window_m,
        yaw_rad: opts.loops.window_deg.to_radians(),
        yaw_step_rad: opts.yaw_step_deg.to_radians(),
    }
}

/// Two rooms joined by a door, with a pillar and an alcove: nothing repeats.
fn two_rooms() -> Vec<[f64; 2]> {
    segments(&[
        ([0.0, 0.0], [12.0, 0.0]),
        ([12.0, 0.0], [12.0, 6.0]),
        ([12.0, 6.0], [0.0, 6.0]),
        ([0.0, 6.0], [0.0, 0.0]),
        ([5.0, 0.0], [5.0, 2.0]),
        ([5.0, 3.2], [5.0, 6.0]),
        ([8.0, 4.0], [8.6, 4.0]),
        ([8.6, 4.0], [8.6, 4.6]),
        ([8.6, 4.6], [8.0, 4.6]),
        ([8.0, 4.6], [8.0, 4.0]),
        ([2.0, 6.0], [2.0, 5.0]),
        ([2.0, 5.0], [3.0, 5.0]),
        ([3.0, 5.0], [3.0, 6.0]),
    ])
}

#[test]
fn closure_matcher_finds_a_known_offset() {
    let world = two_rooms();
    let opts = GraphOptions::default();
    let truth = Pose2::new(6.3, 2.4, 0.4);
    let scan = scan_from(&world, &truth, 8.0, 9);
    assert!(scan.len() >= opts.min_points);
    let field = field_for(&world, [-4.0, -4.0], [16.0, 10.0], &opts);
    // The estimate is off by 1.2 m, 0.9 m and 12 deg (within the default window).
    let guess = truth.compose(&Pose2::new(-1.2, 0.9, 12f64.to_radians()));
    match verify_closure(&field, &scan, &guess, &loop_window(&opts), &opts) {
        Verdict::Accepted(p) => {
            let d = truth.between(&p);
            // Walls here lie on cell boundaries, where the bilinear field is flat over a cell
            // between the two cell centres: the match is exact to about half a cell per axis.
            assert!(d.translation_norm_m() < 0.75 * opts.resolution_m, "{d:?}");
            assert!(d.yaw_rad.abs() < 0.2f64.to_radians(), "{d:?}");
        }
        v => panic!("{v:?}"),
    }
    // A scan from elsewhere (rotated 90 deg, a different place) does not match.
    let other = scan_from(&world, &Pose2::new(2.0, 3.0, 0.0), 8.0, 9);
    let rotated: Vec<[f64; 2]> = other.iter().map(|p| [p[1] * 0.7, -p[0] * 1.3]).collect();
    assert_eq!(
        verify_closure(&field, &rotated, &guess, &loop_window(&opts), &opts),
        Verdict::LowScore
    );
}

#[test]
fn closure_matcher_rejects_a_corridor() {
    // A long featureless corridor 2 m wide: any shift along it fits as well.
    let world = segments(&[([-30.0, 0.0], [30.0, 0.0]), ([-30.0, 2.0], [30.0, 2.0])]);
    let opts = GraphOptions::default();
    let truth = Pose2::new(0.0, 1.0, 0.0);
    let scan = scan_from(&world, &truth, 8.0, 5);
    let field = field_for(&world, [-15.0, -5.0], [15.0, 7.0], &opts);
    let guess = truth.compose(&Pose2::new(0.7, 0.2, 3f64.to_radians()));
    assert_eq!(
        verify_closure(&field, &scan, &guess, &loop_window(&opts), &opts),
        Verdict::Ambiguous
    );
}

/// [`verify_closure_in`] as the local loop search runs it: its window and ambiguity radius.
fn verify_local(
    field: &PointField,
    scan: &[[f64; 2]],
    guess: &Pose2,
    opts: &GraphOptions,
) -> Option<Verdict> {
    let window = SearchWindow {
        xy_m: opts.loops.local.window_m,
        yaw_rad: opts.loops.local.window_deg.to_radians(),
        yaw_step_rad: opts.yaw_step_deg.to_radians(),
    };
    verify_closure_in(
        field,
        scan,
        guess,
        &window,
        opts.loops.local.ambiguity_radius_m,
        true,
        opts,
    )
}

/// `loops.local.search`: around an estimate within the local window of the truth, the local
/// search (+-0.3 m / 2 deg, its smaller ambiguity radius) accepts the very closure the
/// full window finds (the same cell-grid best, so the same refined bits); around an
/// estimate beyond it, the local search finds its best on the window's edge (or nothing),
/// which sends the candidate to the full window.
#[test]
fn local_window_finds_the_full_windows_closure() {
    let world = two_rooms();
    let opts = GraphOptions::default();
    let truth = Pose2::new(6.3, 2.4, 0.4);
    let scan = scan_from(&world, &truth, 8.0, 9);
    let field = field_for(&world, [-4.0, -4.0], [16.0, 10.0], &opts);
    for (dx, dy, dyaw_deg) in [
        (0.12, -0.08, 1.2),
        (-0.15, 0.1, -1.2),
        (0.0, 0.0, 0.0),
        (0.24, 0.21, 0.4),
    ] {
        let guess = truth.compose(&Pose2::new(dx, dy, f64::to_radians(dyaw_deg)));
        let full = verify_closure(&field, &scan, &guess, &loop_window(&opts), &opts);
        let local = verify_local(&field, &scan, &guess, &opts);
        let Verdict::Accepted(p) = full else {
            panic!("{full:?}");
        };
        assert!(truth.between(&p).translation_norm_m() < 0.75 * opts.resolution_m);
        assert_eq!(local, Some(full), "({dx}, {dy}, {dyaw_deg} deg)");
    }
    // 0.6 m and 3 deg off: beyond the local window.
    let guess = truth.compose(&Pose2::new(0.6, -0.1, 3f64.to_radians()));
    let local = verify_local(&field, &scan, &guess, &opts);
    assert!(matches!(local, None | Some(Verdict::LowScore)), "{local:?}");
    assert!(matches!(
        verify_closure(&field, &scan, &guess, &loop_window(&opts), &opts),
        Verdict::Accepted(_)
    ));
}

/// The local search's ambiguity test still rejects a corridor: with a stub on one wall the
/// best pose is the true one, inside the window, but within +-0.3 m a pose 0.15 m or more
/// along the axis scores nearly as well.
#[test]
fn local_window_rejects_a_corridor() {
    let world = segments(&[
        ([-30.0, 0.0], [30.0, 0.0]),
        ([-30.0, 2.0], [30.0, 2.0]),
        ([0.0, 0.0], [0.0, 0.3]),
    ]);
    let opts = GraphOptions::default();
    let truth = Pose2::new(0.0, 1.0, 0.0);
    let scan = scan_from(&world, &truth, 8.0, 5);
    let field = field_for(&world, [-15.0, -5.0], [15.0, 7.0], &opts);
    let guess = truth.compose(&Pose2::new(0.1, 0.05, 1f64.to_radians()));
    let local = verify_local(&field, &scan, &guess, &opts);
    assert_eq!(local, Some(Verdict::Ambiguous));
}

#[test]
fn mit_csail_back_end_beats_the_front_end() {
    let Some(data) = crate::common::data_dir("mit_csail_back_end_beats_the_front_end") else {
        return;
    };
    let dir = data.join("freiburg/mit-csail");
    let bag = dir.join("mit-csail.bag");
    if !bag.is_file() {
        eprintln!(
            "SKIP mit_csail_back_end_beats_the_front_end: {} absent",
            bag.display()
        );
        return;
    }
    use pfslam::eval::relations::{RelationsOptions, evaluate_relations};
    use pfslam::geometry::Trajectory;
    use pfslam_io::relations::read_relations;
    let recording = pfslam_io::recording::read_recording(&bag, &Default::default()).unwrap();
    let relations = read_relations(&dir.join("mit-csail.relations")).unwrap();
    let mut config = pfslam::config::Config::default();
    // A poor front end on purpose (`scan_match`, tuned for the car: 1.66 m here), so the test
    // shows the back end closing the loops by itself; the default `auto` runs `rbpf` here,
    // whose trajectory is already within a few centimetres.
    config.filter.mode = pfslam::filter::FilterMode::ScanMatch;
    // The car's 2 m minimum range, as the front end was tuned with: with every return from
    // 0 m it ends 1.63 m off and the back end behind it at 0.377 m (how much a back end's
    // result depends on its input is measured in docs/decisions/0045).
    config.map.scan.range_min_m = 2.0;
    let slam = pfslam::slam::run_slam(&recording, &config, 1, &mut |_| {}).unwrap();
    let g = pfslam::graph::optimize_trajectory(
        &recording,
        &config.map.scan,
        &slam.trajectory,
        &config.graph,
    )
    .unwrap();
    assert_eq!(g.trajectory.len(), slam.trajectory.len());
    let o = RelationsOptions::default();
    let before =
        evaluate_relations(&Trajectory::new(slam.trajectory.clone()), &relations, &o).unwrap();
    let after = evaluate_relations(&Trajectory::new(g.trajectory), &relations, &o).unwrap();
    eprintln!(
        "mit-csail: front end {:.4} m, back end {:.4} m / {:.3} deg, {:?}",
        before.trans_m.abs.mean, after.trans_m.abs.mean, after.rot_deg.abs.mean, g.stats
    );
    assert!(g.stats.loop_accepted > g.stats.loop_removed_outliers);
    // The target for MIT-CSAIL: the back end behind a poor front end within 0.035 m.
    assert!(
        after.trans_m.abs.mean <= 0.035,
        "{}",
        after.trans_m.abs.mean
    );
    assert!(after.trans_m.abs.mean < 0.1 * before.trans_m.abs.mean);
}

/// The simulated car (tilted LiDAR) driving the example world's 330 m loop twice with a FOG
/// bias 15x the default's (so the dead reckoning drifts by metres), the back end fed the
/// dead reckoning: closures are accepted on the second lap, none is removed as an outlier,
/// and the error falls to a quarter (measured: 0.627 -> 0.162 m).
/// The example world's 330 m loop driven twice with a FOG bias 15x the default's, 50 Hz
/// LiDAR: the recording, its dead reckoning at every scan and the ground truth.
fn biased_loop() -> (
    pfslam::sensors::Recording,
    Vec<pfslam::geometry::StampedPose2>,
    pfslam::geometry::Trajectory,
) {
    use pfslam::geometry::{StampedPose2, Trajectory};
    use pfslam_sim::{SimOptions, World, simulate_car};
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../pfslam-sim/worlds/example.world");
    let world = World::from_file(&path).unwrap();
    let mut opts = SimOptions {
        duration_s: 140.0,
        ..SimOptions::default()
    };
    opts.car.errors.fog_yaw_bias_rad_per_s = 3e-4;
    opts.car.lidar_rate_hz = 50.0;
    let sim = simulate_car(&world, &opts).unwrap();
    let recording = sim
        .recording(&pfslam::motion::MotionOptions::default())
        .unwrap();
    let front: Vec<StampedPose2> = recording
        .scans
        .stamps_ns
        .iter()
        .filter_map(|&s| {
            recording
                .odometry
                .pose_at(s)
                .map(|pose| StampedPose2 { stamp_ns: s, pose })
        })
        .collect();
    (recording, front, Trajectory::new(sim.ground_truth.clone()))
}

/// Prints the aligned ATE of the dead reckoning `front` and of the back end `g` on
/// [`biased_loop`]'s drive, and asserts that `g` removes most of the drift.
fn assert_removes_the_drift(
    label: &str,
    front: &[pfslam::geometry::StampedPose2],
    g: &pfslam::graph::GraphResult,
    gt: &pfslam::geometry::Trajectory,
) {
    use pfslam::eval::{Association, ate::ate};
    use pfslam::geometry::Trajectory;
    let assoc = Association::Nearest { tolerance_ns: 0 };
    let rmse = |poses: &[pfslam::geometry::StampedPose2]| {
        ate(&Trajectory::new(poses.to_vec()), gt, assoc)
            .unwrap()
            .aligned_m
            .rmse
    };
    let (before, after) = (rmse(front), rmse(&g.trajectory));
    eprintln!(
        "{label}: dead reckoning {before:.3} m -> back end {after:.3} m, {:?}",
        g.stats
    );
    assert!(after < 0.4 * before, "{after} vs {before}");
}

/// The back end of `g` run again with one keyframe's loop search at a time: asserts the same
/// trajectory, closures and final cost to the bit, and returns it for further checks.
fn one_keyframe_at_a_time(
    recording: &pfslam::sensors::Recording,
    config: &pfslam::config::Config,
    front: &[pfslam::geometry::StampedPose2],
    g: &pfslam::graph::GraphResult,
) -> pfslam::graph::GraphResult {
    let one = pfslam::graph::optimize_trajectory_look_ahead(
        recording,
        &config.map.scan,
        front,
        &config.graph,
        1,
    )
    .unwrap();
    assert_eq!(one.trajectory, g.trajectory);
    assert_eq!(one.loop_edges, g.loop_edges);
    assert_eq!(one.stats.final_cost.to_bits(), g.stats.final_cost.to_bits());
    one
}

#[test]
fn simulated_car_loop_closes_on_dead_reckoning() {
    let (recording, front, gt) = biased_loop();
    let mut config = pfslam::config::Config::default();
    // The front end is the odometry itself, so an odometry-yaw edge would count its yaw
    // twice, and this FOG's bias is far beyond that edge's default uncertainty.
    config.graph.sequential.odometry_yaw_sigma_deg_per_sqrt_m = 0.0;
    let g = pfslam::graph::optimize_trajectory(&recording, &config.map.scan, &front, &config.graph)
        .unwrap();
    assert_eq!(g.stats.loop_local, 0, "loop_local_search auto: off here");
    assert_removes_the_drift("simulated loop", &front, &g, &gt);
    assert_eq!(
        g.stats.sequential_matched, 0,
        "tilted LiDAR: no sequential matching"
    );
    assert!(g.stats.loop_accepted >= 20, "{:?}", g.stats);
    assert_eq!(g.stats.loop_removed_outliers, 0);
    // The loop searches of several keyframes verified in one parallel batch (the default)
    // give the bits of one keyframe at a time.
    let one = one_keyframe_at_a_time(&recording, &config, &front, &g);
    assert_eq!(
        (
            one.stats.loop_candidates,
            one.stats.loop_accepted,
            one.stats.optimizations
        ),
        (
            g.stats.loop_candidates,
            g.stats.loop_accepted,
            g.stats.optimizations
        )
    );
}

/// `loops.local.search` on the loop of `simulated_car_loop_closes_on_dead_reckoning`, from
/// the first consistent closure on (`loops.local.min_closures = 1`): the candidates before
/// the first optimisation (no closure vouches yet) are searched in the full window, most
/// later ones in the local window, some of those again in the full one (the dead
/// reckoning's FOG bias moves the estimate by decimetres between optimisations: best pose
/// on the local window's edge); the loop still closes, no closure is removed, and the
/// look-ahead (the local decision depends on the last optimisation only) gives the bits of
/// one keyframe at a time. With the default `loops.local.min_closures` (200) this short loop
/// never has enough closures for a local search.
#[test]
fn simulated_car_local_loop_search() {
    use pfslam::graph::Switch;
    let (recording, front, gt) = biased_loop();
    let mut config = pfslam::config::Config::default();
    config.graph.sequential.odometry_yaw_sigma_deg_per_sqrt_m = 0.0;
    config.graph.loops.local.search = Switch::On;
    let few =
        pfslam::graph::optimize_trajectory(&recording, &config.map.scan, &front, &config.graph)
            .unwrap();
    assert!(few.stats.loop_accepted < config.graph.loops.local.min_closures);
    assert_eq!(few.stats.loop_local, 0, "{:?}", few.stats);
    config.graph.loops.local.min_closures = 1;
    let g = pfslam::graph::optimize_trajectory(&recording, &config.map.scan, &front, &config.graph)
        .unwrap();
    assert_removes_the_drift("simulated loop, local search", &front, &g, &gt);
    let s = &g.stats;
    assert!(s.loop_local > s.loop_candidates / 2, "{s:?}");
    assert!(s.loop_local < s.loop_candidates, "full window first: {s:?}");
    assert!(s.loop_local_fallbacks < s.loop_local, "{s:?}");
    assert!(s.loop_accepted >= 20, "{s:?}");
    assert_eq!(s.loop_removed_outliers, 0);
    let one = one_keyframe_at_a_time(&recording, &config, &front, &g);
    assert_eq!(one.stats.loop_local, s.loop_local);
    assert_eq!(one.stats.loop_local_fallbacks, s.loop_local_fallbacks);
}

/// The humanoid (LiDAR on a moving head, odometry yaw from the legs, not a gyro): the back end
/// adds no odometry-yaw edges there (`[graph.sequential] odometry_yaw_edges = "auto"`) and does not make
/// the filter's trajectory worse. With those edges (tuned for the car's FOG) it pulled the
/// default 180 s walk from 0.138 to 0.369 m ATE (`pfslam run`, seed 1); without them
/// 0.130 m (seeds 2, 3: 0.143 -> 0.132, 0.133 -> 0.129 m). Here: 0.157 -> 0.147 m.
#[test]
fn humanoid_back_end_takes_no_odometry_yaw_edges() {
    use pfslam::eval::{Association, ate::ate};
    use pfslam::geometry::Trajectory;
    use pfslam::pipeline::{PipelineOptions, run_pipeline};
    use pfslam_sim::{SimOptions, Vehicle, World, simulate_humanoid};
    let opts = SimOptions {
        vehicle: Vehicle::Humanoid,
        ..SimOptions::default()
    };
    let sim = simulate_humanoid(&World::builtin("office").unwrap(), &opts).unwrap();
    let recording = sim.recording();
    let config = pfslam::config::Config::default();
    let out = run_pipeline(
        &recording,
        &config,
        1,
        &PipelineOptions::default(),
        &mut |_| {},
    )
    .unwrap();
    let stats = out.graph.clone().expect("the back end ran");
    let gt = Trajectory::new(sim.ground_truth.clone());
    let assoc = Association::Nearest { tolerance_ns: 0 };
    let front = ate(&Trajectory::new(out.front_end.clone()), &gt, assoc).unwrap();
    let back = ate(&Trajectory::new(out.result.trajectory.clone()), &gt, assoc).unwrap();
    eprintln!(
        "humanoid: front end {:.3} m -> back end {:.3} m, {stats:?}",
        front.aligned_m.rmse, back.aligned_m.rmse
    );
    assert_eq!(stats.odometry_yaw_edges, 0, "{stats:?}");
    assert!(
        back.aligned_m.rmse <= 1.05 * front.aligned_m.rmse,
        "{} vs {}",
        back.aligned_m.rmse,
        front.aligned_m.rmse
    );
}
