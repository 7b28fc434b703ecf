//! Ctrl-C, `kill` and a closed terminal (SIGINT, SIGTERM, SIGHUP) end a run at once and
//! take its staging directories with them: the previous outputs stay as they were and no
//! temporary files are left behind. (A `kill -9` cannot be caught: the next run beside the
//! same `--out` removes what it left.)

use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Staging directories to remove when a signal ends the run.
static STAGING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Starts the thread that waits for the signals (once, at start-up).
#[cfg(unix)]
pub fn install() {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]) else {
        return;
    };
    std::thread::spawn(move || {
        if let Some(signal) = signals.forever().next() {
            remove_all();
            std::process::exit(128 + signal);
        }
    });
}

/// Without Unix signals: the default handling (the next run sweeps what was left).
#[cfg(not(unix))]
pub fn install() {}

/// Removes `dir` if a signal ends the run before [`forget`].
pub fn remember(dir: &Path) {
    if let Ok(mut dirs) = STAGING.lock() {
        dirs.push(dir.to_path_buf());
    }
}

/// `dir` is committed or dropped: no longer removed on a signal.
pub fn forget(dir: &Path) {
    if let Ok(mut dirs) = STAGING.lock() {
        dirs.retain(|d| d != dir);
    }
}

fn remove_all() {
    let dirs = match STAGING.lock() {
        Ok(mut dirs) => std::mem::take(&mut *dirs),
        Err(_) => return,
    };
    for dir in dirs {
        let _ = std::fs::remove_dir_all(dir);
    }
}
