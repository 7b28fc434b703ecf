//! Replays every committed fuzz input (`fuzz/corpus/<target>/` and `fuzz/regressions/<target>/`)
//! through its target, under the same allocation cap as the fuzzing runs, and times each:
//! the corpus and every input that once crashed or hung stay covered by `cargo test`.

use pfslam_fuzz_harness::{CappedAlloc, TARGETS, remove_scratch_dir, set_input_len};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

#[global_allocator]
static ALLOC: CappedAlloc = CappedAlloc;

/// Slowest accepted input, as the fuzzing runs' hang limit.
const MAX_INPUT_TIME: Duration = Duration::from_secs(1);

fn inputs(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    files
}

/// One test for all targets: the allocation cap is process-wide, so inputs run one at a time.
#[test]
fn replay_corpus_and_regressions() {
    let fuzz_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut total = 0usize;
    let mut slow = Vec::new();
    for (name, target) in TARGETS {
        let mut count = 0usize;
        for kind in ["corpus", "regressions"] {
            for file in inputs(&fuzz_dir.join(kind).join(name)) {
                let data = std::fs::read(&file).expect("read a fuzz input");
                eprintln!("{name}: {}", file.display());
                set_input_len(data.len());
                let t0 = Instant::now();
                target(&data);
                let took = t0.elapsed();
                set_input_len(usize::MAX / 2);
                if took > MAX_INPUT_TIME {
                    slow.push(format!("{} ({took:?})", file.display()));
                }
                count += 1;
            }
        }
        assert!(count > 0, "target {name} has no committed input");
        total += count;
    }
    remove_scratch_dir();
    assert!(
        slow.is_empty(),
        "inputs slower than {MAX_INPUT_TIME:?}: {slow:?}"
    );
    eprintln!("replayed {total} fuzz inputs");
}
