//! End-to-end tests of the `pfslam` binary.

mod cli_simulate;

use std::process::Command;

fn pfslam() -> Command {
    Command::new(env!("CARGO_BIN_EXE_pfslam"))
}

/// The developers' tool (`bench-e2e`, `experiment`).
fn pfslam_dev() -> Command {
    Command::new(env!("CARGO_BIN_EXE_pfslam-dev"))
}

/// Asserts that a run succeeded, showing its stderr otherwise.
fn assert_ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Simulates a 6 s drive into `dir/sim` and writes `dir/run.toml` (a map snapshot every 200
/// scans); returns both paths.
fn short_simulated_drive(dir: &std::path::Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let data = dir.join("sim");
    run_ok(
        pfslam()
            .args(["simulate", "--duration-s", "6", "--out"])
            .arg(&data),
    );
    let cfg = dir.join("run.toml");
    std::fs::write(&cfg, "[filter]\nsnapshot_every_scans = 200\n").unwrap();
    (data, cfg)
}

/// The real-data directory (`$PFSLAM_DATA` or `shared/data` beside the workspace root), or
/// `None` after printing a skip notice naming the test.
fn data_dir(test: &str) -> Option<std::path::PathBuf> {
    let d = pfslam_io::data_root(env!("CARGO_MANIFEST_DIR"));
    if d.is_none() {
        eprintln!("SKIP {test}: no real data");
    }
    d
}

/// Runs the command and asserts it succeeded.
fn run_ok(cmd: &mut Command) -> std::process::Output {
    let out = cmd.output().unwrap();
    assert_ok(&out);
    out
}

#[test]
fn print_config_is_valid_toml() {
    let out = pfslam().arg("print-config").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    let parsed: Result<pfslam::config::Config, _> = toml::from_str(&text);
    assert!(parsed.is_ok(), "{text}");
}

#[test]
fn unknown_subcommand_exits_2() {
    let out = pfslam().arg("no-such-command").output().unwrap();
    assert_eq!(out.status.code(), Some(2));
}

mod cli_bench_e2e;
mod cli_benchmark;
mod cli_data;
mod cli_demo;
mod cli_eval;
mod cli_live;
mod cli_map;
mod cli_record;
mod cli_run;
mod cli_sim_texture;
mod cli_stream;
mod cli_texture;

#[test]
fn a_closed_pipe_ends_quietly() {
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let sim = dir.path().join("sim");
    let sim_arg = sim.to_str().unwrap();
    // like `pfslam print-config | head -1`: the reader is gone before the text is written;
    // the same for a command that reports as it works
    for args in [
        vec!["print-config"],
        vec!["simulate", "--duration-s", "2", "--out", sim_arg],
    ] {
        let mut child = pfslam()
            .args(&args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(0), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    assert!(sim.join("ground_truth.tum").is_file(), "the work was done");
}
