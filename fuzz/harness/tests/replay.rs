//! Replays fuzz inputs through their targets, under the same allocation cap as the fuzzing
//! runs, and times each:
//! - the committed seeds, made by the simulator and by hand (`fuzz/corpus/<target>/`);
//! - seeds cut at test time from the real recordings in `$PFSLAM_DATA` (real data stays out
//!   of the repository; `fuzz/scripts/seeds.sh` cuts the same ones for fuzzing);
//! - the inputs that once made a reader allocate gigabytes, rebuilt from a real recording
//!   with the corrupt length written in, each also checked for the reader's error.

use pfslam_fuzz_harness::{
    CappedAlloc, TARGETS, remove_scratch_dir, scratch_dir, set_input_len, target,
};
use pfslam_io::options::ReaderOptions;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

#[global_allocator]
static ALLOC: CappedAlloc = CappedAlloc;

/// Slowest accepted input, as the fuzzing runs' hang limit.
const MAX_INPUT_TIME: Duration = Duration::from_secs(1);

/// Targets whose seeds are cut from real recordings, never committed.
const DATA_TARGETS: [&str; 6] = [
    "carmen",
    "ros1_bag",
    "mcap",
    "relations",
    "ucsd_calib",
    "opencv_yaml",
];

/// One input: its target, a label for messages, the bytes.
struct Input {
    target: &'static str,
    label: String,
    bytes: Vec<u8>,
}

fn committed_inputs(fuzz_dir: &Path) -> Vec<Input> {
    let mut out = Vec::new();
    for (name, _) in TARGETS {
        let Ok(entries) = std::fs::read_dir(fuzz_dir.join("corpus").join(name)) else {
            continue;
        };
        let mut files: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file())
            .collect();
        files.sort();
        for file in files {
            out.push(Input {
                target: name,
                label: file.display().to_string(),
                bytes: std::fs::read(&file).expect("read a fuzz seed"),
            });
        }
    }
    out
}

/// The first whole lines of `text` within `max_bytes`, comment lines (`#`) left out.
fn head_lines(text: &[u8], max_bytes: usize) -> Vec<u8> {
    let mut out = Vec::new();
    for line in text.split_inclusive(|&b| b == b'\n') {
        if line.starts_with(b"#") {
            continue;
        }
        if out.len() + line.len() > max_bytes {
            break;
        }
        out.extend_from_slice(line);
    }
    out
}

fn gunzip(path: &Path) -> Vec<u8> {
    let mut text = Vec::new();
    flate2::read::GzDecoder::new(std::fs::File::open(path).expect("open a log"))
        .read_to_end(&mut text)
        .expect("gunzip a log");
    text
}

/// A small MCAP written by the library from the first scans of a CARMEN log.
fn small_mcap(data: &Path, out: &Path) -> Vec<u8> {
    let log = data.join("carmen/seattle-corrected.log.gz");
    let mut rec = pfslam_io::recording::read_recording(&log, &ReaderOptions::default())
        .expect("read the seattle log");
    rec.keep_scans(&(0..20).collect::<Vec<_>>());
    pfslam_io::mcap::write_mcap(out, &rec, &ReaderOptions::default()).expect("write an MCAP");
    std::fs::read(out).expect("read the MCAP back")
}

/// Seeds cut from the real recordings (as `fuzz/scripts/seeds.sh` does, a few KB each).
fn data_inputs(data: &Path, scratch: &Path) -> Vec<Input> {
    let input = |target, label: &str, bytes| Input {
        target,
        label: format!("{label} (cut from $PFSLAM_DATA)"),
        bytes,
    };
    let read = |p: &str| std::fs::read(data.join(p)).expect("read a recording");
    let mut out = vec![input(
        "carmen",
        "mit-csail.clf",
        head_lines(&read("freiburg/mit-csail/mit-csail.clf"), 6000),
    )];
    for log in ["intel", "orebro", "seattle", "acapulco"] {
        let text = gunzip(&data.join(format!("carmen/{log}-corrected.log.gz")));
        out.push(input("carmen", log, head_lines(&text, 6000)));
    }
    for bag in ["freiburg/mit-csail/mit-csail.bag", "freiburg/aces/aces.bag"] {
        // The bag's header and the start of its first chunk: the reader's error paths.
        let mut bytes = read(bag);
        bytes.truncate(16 * 1024);
        out.push(input("ros1_bag", bag, bytes));
    }
    out.push(input(
        "mcap",
        "seattle.mcap",
        small_mcap(data, &scratch.join("seed.mcap")),
    ));
    for r in ["aces", "intel", "mit-csail"] {
        let text = read(&format!("freiburg/{r}/{r}.relations"));
        out.push(input("relations", r, head_lines(&text, 3000)));
    }
    for f in [
        "EncoderParameter.txt",
        "Vehicle2FOG.txt",
        "Vehicle2Lidar.txt",
        "Vehicle2Stereo.txt",
        "lidar_param.txt",
        "stereo_param.txt",
    ] {
        out.push(input("ucsd_calib", f, read(&format!("ucsd/param/{f}"))));
    }
    for f in ["left_camera.yaml", "right_camera.yaml"] {
        out.push(input("opencv_yaml", f, read(&format!("ucsd/param/{f}"))));
    }
    out
}

/// Offset of the `size=` value in the header of the bag's first chunk record.
fn first_chunk_size_field(bag: &[u8]) -> Option<usize> {
    let u32_at = |at: usize| -> Option<usize> {
        let b = bag.get(at..at + 4)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
    };
    let mut at = b"#ROSBAG V2.0\n".len();
    while at < bag.len() {
        let header_len = u32_at(at)?;
        let (header_at, data_len_at) = (at + 4, at + 4 + header_len);
        let (mut p, mut op, mut size) = (header_at, None, None);
        while p < data_len_at {
            let l = u32_at(p)?;
            let field = bag.get(p + 4..p + 4 + l)?;
            if field.starts_with(b"op=") {
                op = field.get(3).copied();
            } else if field.starts_with(b"size=") {
                size = Some(p + 4 + 5);
            }
            p += 4 + l;
        }
        if op == Some(0x05) {
            return size;
        }
        at = data_len_at + 4 + u32_at(data_len_at)?;
    }
    None
}

/// The inputs that once made a reader allocate gigabytes, with the error each must give
/// now: a real bag whose first chunk claims 4 GB, and an MCAP whose Header's first string
/// claims 4 GiB.
fn regressions(data: &Path, scratch: &Path) -> Vec<(Input, &'static str)> {
    let mut bag = std::fs::read(data.join("freiburg/mit-csail/mit-csail.bag")).expect("read");
    let at = first_chunk_size_field(&bag).expect("the bag has a chunk with a size");
    bag[at..at + 4].copy_from_slice(&0xF500_0000u32.to_le_bytes());
    let mut mcap = small_mcap(data, &scratch.join("regression.mcap"));
    // Magic (8 bytes), the Header record's opcode and u64 length, then its profile's length.
    assert_eq!(mcap[8], 0x01, "an MCAP starts with its Header record");
    mcap[17..21].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    vec![
        (
            Input {
                target: "ros1_bag",
                label: "mit-csail.bag, first chunk's size 4 GB".into(),
                bytes: bag,
            },
            "decompressed bytes",
        ),
        (
            Input {
                target: "mcap",
                label: "seattle.mcap, Header string of 4 GiB".into(),
                bytes: mcap,
            },
            "runs past its end",
        ),
    ]
}

/// Runs `input` through its target under the cap; returns its time.
fn replay(input: &Input) -> Duration {
    let run = target(input.target).expect("a known target");
    eprintln!("{}: {}", input.target, input.label);
    set_input_len(input.bytes.len());
    let t0 = Instant::now();
    run(&input.bytes);
    let took = t0.elapsed();
    set_input_len(usize::MAX / 2);
    took
}

/// The reader's error on a regression input (read under the cap, as the target reads it).
fn reader_error(input: &Input, scratch: &Path) -> String {
    let ext = if input.target == "mcap" {
        "mcap"
    } else {
        "bag"
    };
    let path = scratch.join(format!("regression.{ext}"));
    std::fs::write(&path, &input.bytes).expect("write a regression input");
    set_input_len(input.bytes.len());
    let result = pfslam_io::recording::read_recording(&path, &ReaderOptions::default());
    set_input_len(usize::MAX / 2);
    match result {
        Ok(_) => panic!("{}: read without an error", input.label),
        Err(e) => e.to_string(),
    }
}

/// One test for all inputs: the allocation cap is process-wide, so inputs run one at a time.
#[test]
fn replay_seeds_and_regressions() {
    let fuzz_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let scratch = scratch_dir();
    let mut inputs = committed_inputs(&fuzz_dir);
    let data = pfslam_io::data_root(env!("CARGO_MANIFEST_DIR"));
    let mut checks = Vec::new();
    match &data {
        Some(data) => {
            inputs.extend(data_inputs(data, &scratch));
            checks = regressions(data, &scratch);
        }
        None => eprintln!(
            "SKIP the seeds of {DATA_TARGETS:?} and the regressions: no real data \
             ($PFSLAM_DATA)"
        ),
    }
    for (name, _) in TARGETS {
        let needed = data.is_some() || !DATA_TARGETS.contains(name);
        let count = inputs.iter().filter(|i| i.target == *name).count();
        assert!(!needed || count > 0, "target {name} has no input");
    }
    let mut slow = Vec::new();
    for input in inputs.iter().chain(checks.iter().map(|(i, _)| i)) {
        let took = replay(input);
        if took > MAX_INPUT_TIME {
            slow.push(format!("{} ({took:?})", input.label));
        }
    }
    for (input, expected) in &checks {
        let error = reader_error(input, &scratch);
        assert!(error.contains(expected), "{}: {error}", input.label);
    }
    remove_scratch_dir();
    assert!(
        slow.is_empty(),
        "inputs slower than {MAX_INPUT_TIME:?}: {slow:?}"
    );
    eprintln!("replayed {} fuzz inputs", inputs.len() + checks.len());
}
