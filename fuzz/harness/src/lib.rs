//! The fuzz targets of pfslam's readers: each takes arbitrary bytes, hands them to one reader
//! and ignores whether it returned `Ok` or `Err`. A target must never panic, abort, hang or
//! allocate far more than its input; the fuzzing engine (`fuzz/afl`) and the replay test
//! (`tests/replay.rs`, run by `cargo test`) both call these functions.
//!
//! Every reader has a twin that takes bytes, text or a byte source, and the targets call those;
//! only the ROS 1 bag (the `rosbag` crate maps a file) gets its bytes through a scratch file.
//! Inputs of multi-file layouts (map_server, humanoid) are split on NUL bytes, which none of
//! their text files holds.

use pfslam_io::IoError;
use pfslam_io::options::ReaderOptions;
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// A fuzz target: bytes in, nothing out.
pub type Target = fn(&[u8]);

/// Every target by name (the name of its AFL binary and of its corpus folder).
pub const TARGETS: &[(&str, Target)] = &[
    ("carmen", carmen),
    ("ros1_bag", ros1_bag),
    ("mcap", mcap),
    ("ucsd_encoder", ucsd_encoder),
    ("ucsd_fog", ucsd_fog),
    ("ucsd_lidar", ucsd_lidar),
    ("ucsd_calib", ucsd_calib),
    ("opencv_yaml", opencv_yaml),
    ("humanoid", humanoid),
    ("tum", tum),
    ("map_server", map_server),
    ("npy", npy),
    ("relations", relations),
    ("config_toml", config_toml),
    ("session_state", session_state),
];

/// The target called `name`.
pub fn target(name: &str) -> Option<Target> {
    TARGETS.iter().find(|(n, _)| *n == name).map(|&(_, t)| t)
}

/// Largest single allocation allowed for any input, plus [`ALLOC_BYTES_PER_INPUT_BYTE`] per
/// byte of input: fixed-size read buffers fit under it, a length field taken on trust does not.
pub const ALLOC_BASE_BYTES: usize = 32 << 20;
/// See [`ALLOC_BASE_BYTES`].
pub const ALLOC_BYTES_PER_INPUT_BYTE: usize = 64;

static ALLOC_LIMIT_BYTES: AtomicUsize = AtomicUsize::new(usize::MAX);

/// Sets the allocation cap of [`CappedAlloc`] for an input of `input_len` bytes.
pub fn set_input_len(input_len: usize) {
    let limit = input_len
        .saturating_mul(ALLOC_BYTES_PER_INPUT_BYTE)
        .saturating_add(ALLOC_BASE_BYTES);
    ALLOC_LIMIT_BYTES.store(limit, Ordering::Relaxed);
}

/// A global allocator that aborts on any single allocation above the cap set by
/// [`set_input_len`]: an allocation sized by an unchecked length field shows up as a crash
/// even where the machine would have granted the memory.
pub struct CappedAlloc;

impl CappedAlloc {
    fn check(size: usize) {
        if size > ALLOC_LIMIT_BYTES.load(Ordering::Relaxed) {
            // No formatting here: it could allocate.
            let msg: &[u8] = b"pfslam-fuzz: allocation above the cap for this input size\n";
            let _ = std::io::Write::write_all(&mut std::io::stderr(), msg);
            std::process::abort();
        }
    }
}

// SAFETY: every call is forwarded to the system allocator unchanged; the cap only aborts.
unsafe impl GlobalAlloc for CappedAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        Self::check(layout.size());
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        Self::check(layout.size());
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        Self::check(new_size);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// The scratch directory of this thread: under `$PFSLAM_FUZZ_TMP` (else `/dev/shm` when it
/// exists, else the system's temporary directory), named by the parent process and the
/// thread, so that the processes an AFL fork server starts one after another reuse one folder.
pub fn scratch_dir() -> PathBuf {
    use std::cell::OnceCell;
    static NEXT_THREAD: AtomicUsize = AtomicUsize::new(0);
    thread_local! {
        static DIR: OnceCell<PathBuf> = const { OnceCell::new() };
    }
    DIR.with(|d| {
        d.get_or_init(|| {
            let root = match std::env::var_os("PFSLAM_FUZZ_TMP") {
                Some(r) => PathBuf::from(r),
                None if Path::new("/dev/shm").is_dir() => PathBuf::from("/dev/shm"),
                None => std::env::temp_dir(),
            };
            let thread = NEXT_THREAD.fetch_add(1, Ordering::Relaxed);
            let dir = root.join(format!(
                "pfslam-fuzz-{}-{}-{thread}",
                std::os::unix::process::parent_id(),
                std::process::id()
            ));
            // The fork server's children share the fork server's pid as parent; the pid of
            // the first child is not reused, so name by the parent only there.
            let dir = if std::env::var_os("__AFL_SHM_ID").is_some() {
                root.join(format!(
                    "pfslam-fuzz-{}-{thread}",
                    std::os::unix::process::parent_id()
                ))
            } else {
                dir
            };
            let _ = std::fs::create_dir_all(&dir);
            dir
        })
        .clone()
    })
}

/// Removes this thread's scratch directory (the replay test calls it at the end).
pub fn remove_scratch_dir() {
    let _ = std::fs::remove_dir_all(scratch_dir());
}

/// Writes `bytes` to `name` in the scratch directory and returns its path.
fn scratch_file(name: &str, bytes: &[u8]) -> PathBuf {
    let dir = scratch_dir();
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join(name);
    let _ = std::fs::write(&path, bytes);
    path
}

/// CARMEN log (plain or gzip), lenient and strict.
pub fn carmen(data: &[u8]) {
    use pfslam_io::carmen::{CarmenOptions, read_carmen_from};
    for strict in [false, true] {
        let options = CarmenOptions {
            strict,
            ..CarmenOptions::default()
        };
        let _ = read_carmen_from(data, Path::new("log.clf"), &options);
    }
}

/// ROS 1 bag: topics from the index, then the whole recording.
pub fn ros1_bag(data: &[u8]) {
    let path = scratch_file("in.bag", data);
    let _ = pfslam_io::ros1::read_ros1_bag(&path, &ReaderOptions::default());
}

/// MCAP (ROS 2, CDR).
pub fn mcap(data: &[u8]) {
    let path = Path::new("in.mcap");
    let _ = pfslam_io::mcap::read_mcap_from_bytes(data, path, &ReaderOptions::default());
}

/// The UCSD car's options: both timestamp policies are reachable from the CLI.
fn ucsd_options() -> [pfslam_io::ucsd::ReadOptions; 2] {
    use pfslam_io::ucsd::{ReadOptions, TimestampPolicy};
    [TimestampPolicy::Reject, TimestampPolicy::SortWithWarning].map(|timestamp_policy| {
        ReadOptions {
            timestamp_policy,
            ..ReadOptions::default()
        }
    })
}

/// The UCSD car's `encoder.csv`, with its real wheel calibration.
pub fn ucsd_encoder(data: &[u8]) {
    use pfslam::sensors::EncoderParams;
    use pfslam_io::ucsd::read_encoder_csv_from;
    let params = EncoderParams::default();
    for opts in ucsd_options() {
        let _ = read_encoder_csv_from(data, Path::new("encoder.csv"), &params, &opts);
    }
}

/// The UCSD car's `fog.csv`.
pub fn ucsd_fog(data: &[u8]) {
    for opts in ucsd_options() {
        let _ = pfslam_io::ucsd::read_fog_csv_from(data, Path::new("fog.csv"), &opts);
    }
}

/// The UCSD car's `lidar.csv`; the first byte picks the beam count (the calibration's).
pub fn ucsd_lidar(data: &[u8]) {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let beam_count = [286, 1, 4, usize::from(first)][usize::from(first % 4)];
    for opts in ucsd_options() {
        let path = Path::new("lidar.csv");
        let _ = pfslam_io::ucsd::read_lidar_csv_from(rest, path, beam_count, &opts);
    }
}

/// The UCSD car's calibration text files: every parser on the same bytes.
pub fn ucsd_calib(data: &[u8]) {
    use pfslam_io::ucsd::calib::{
        parse_encoder_params, parse_extrinsic, parse_lidar_params, parse_stereo_baseline_m,
    };
    // The files are read as UTF-8 text; other bytes are refused before any parser.
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("param.txt");
    let _ = parse_encoder_params(text, path);
    let _ = parse_extrinsic(text, path);
    let _ = parse_lidar_params(text, path);
    let _ = parse_stereo_baseline_m(text, path);
}

/// OpenCV YAML camera file (`%YAML:1.0`, `!!opencv-matrix`).
pub fn opencv_yaml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = pfslam_io::opencv_yaml::parse_camera_yaml(Path::new("camera.yaml"), text);
}

/// The humanoid layout: calibration, odometry, IMU, joints and LiDAR files, NUL-separated.
pub fn humanoid(data: &[u8]) {
    use pfslam_io::humanoid::{
        CALIBRATION_FILE, IMU_CSV, JOINTS_CSV, LIDAR_CSV, ODOMETRY_CSV, read_humanoid_dataset_with,
    };
    let names = [
        CALIBRATION_FILE,
        ODOMETRY_CSV,
        IMU_CSV,
        JOINTS_CSV,
        LIDAR_CSV,
    ];
    let dir = Path::new("humanoid");
    let _ = read_humanoid_dataset_with(dir, |path| {
        let k = names.iter().position(|n| dir.join(n) == path);
        match k.and_then(|k| data.splitn(names.len(), |&b| b == 0).nth(k)) {
            Some(part) => String::from_utf8(part.to_vec()).map_err(|e| {
                IoError::io(
                    path,
                    std::io::Error::new(std::io::ErrorKind::InvalidData, e),
                )
            }),
            None => Err(IoError::Missing {
                path: path.to_path_buf(),
                what: "humanoid dataset file".to_string(),
            }),
        }
    });
}

/// TUM trajectory.
pub fn tum(data: &[u8]) {
    let _ = pfslam_io::tum::read_tum_from(data, Path::new("poses.tum"));
}

/// map_server pair: the yaml, a NUL, then the pgm (written as `map.pgm`, the seeds' image).
pub fn map_server(data: &[u8]) {
    let mut parts = data.splitn(2, |&b| b == 0);
    let Ok(yaml) = std::str::from_utf8(parts.next().unwrap_or_default()) else {
        return;
    };
    let pgm = parts.next();
    let yaml_path = Path::new("map.yaml");
    let _ = pfslam_io::map_files::parse_map_server(yaml, yaml_path, |image| match pgm {
        Some(p) if image == Path::new("map.pgm") => Ok(p.to_vec()),
        _ => Err(std::io::ErrorKind::NotFound.into()),
    });
}

/// NPY `<f4` array (the log-odds maps).
pub fn npy(data: &[u8]) {
    let _ = pfslam_io::map_files::parse_npy_f32(data, Path::new("map.npy"));
}

/// Freiburg `.relations` file.
pub fn relations(data: &[u8]) {
    let _ = pfslam_io::relations::read_relations_from(data, Path::new("in.relations"));
}

/// A saved session's state (`run --save-state`), decoded from the bytes directly.
pub fn session_state(data: &[u8]) {
    let _ = pfslam::session::SessionState::from_bytes(data, "state.pfslam");
}

/// TOML configuration, loaded and validated as the CLI does.
pub fn config_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(c) = pfslam::config::Config::from_toml_str(text, Path::new("config.toml")) {
        let _ = c.validate();
    }
}
