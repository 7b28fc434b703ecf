//! An output directory written as one unit: a command writes into a staging directory beside
//! `--out` and [`Staging::commit`] moves its files into place at the end. A failed or killed
//! run leaves the previous outputs as they were. Over an existing `--out`, the files a
//! previous run listed in its `manifest.json` and this run did not write are removed, so no
//! stale output sits beside the new ones; files the user put there are left alone.

use anyhow::Context;
use std::path::{Path, PathBuf};

/// The list of the files a run wrote, relative to `--out`.
pub const MANIFEST: &str = "manifest.json";
/// Staging directories are named `<PREFIX><pid>-<random>` in `--out`'s parent.
const PREFIX: &str = ".pfslam-staging-";

/// A staging directory for one `--out`.
pub struct Staging {
    out: PathBuf,
    dir: tempfile::TempDir,
}

impl Staging {
    /// Checks that `out` can be written (not a file, its parent a directory that accepts
    /// files) and makes the staging directory beside it. Staging directories that killed runs
    /// left there are removed.
    pub fn new(out: &Path) -> anyhow::Result<Staging> {
        if out.exists() && !out.is_dir() {
            anyhow::bail!("--out {}: exists and is not a directory", out.display());
        }
        let parent = match out.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&parent).with_context(|| {
            format!(
                "--out {}: cannot create {}",
                out.display(),
                parent.display()
            )
        })?;
        sweep_stale(&parent);
        let dir = tempfile::Builder::new()
            .prefix(&format!("{PREFIX}{}-", std::process::id()))
            .tempdir_in(&parent)
            .with_context(|| {
                format!(
                    "--out {}: cannot write in {}",
                    out.display(),
                    parent.display()
                )
            })?;
        if out.is_dir() {
            // the files are renamed into it at the end: it must accept them
            tempfile::Builder::new()
                .prefix(".pfslam-probe-")
                .tempfile_in(out)
                .with_context(|| format!("--out {}: cannot write into it", out.display()))?;
        }
        super::interrupt::remember(dir.path());
        Ok(Staging {
            out: out.to_path_buf(),
            dir,
        })
    }

    /// Where the command writes its outputs.
    pub fn path(&self) -> &Path {
        self.dir.path()
    }

    /// Moves the outputs into `--out`, writes its manifest and removes the stale files of
    /// the previous run.
    pub fn commit(self) -> anyhow::Result<()> {
        // from here a signal leaves the files to finish moving (the next run sweeps the rest)
        super::interrupt::forget(self.dir.path());
        let files = relative_files(self.dir.path())?;
        let manifest = serde_json::to_string_pretty(&serde_json::json!({ "files": files }))?;
        std::fs::write(self.dir.path().join(MANIFEST), manifest)?;
        if !self.out.exists() {
            let staged = self.dir.keep();
            return std::fs::rename(&staged, &self.out)
                .with_context(|| format!("moving the outputs to {}", self.out.display()));
        }
        let previous = read_manifest(&self.out);
        for f in files.iter().map(String::as_str).chain([MANIFEST]) {
            let to = self.out.join(f);
            if let Some(p) = to.parent() {
                std::fs::create_dir_all(p)?;
            }
            std::fs::rename(self.dir.path().join(f), &to)
                .with_context(|| format!("moving {f} into {}", self.out.display()))?;
        }
        for stale in previous.iter().filter(|f| !files.contains(f)) {
            let _ = std::fs::remove_file(self.out.join(stale));
        }
        Ok(())
    }
}

/// The files below `dir`, relative, sorted (`/`-separated).
fn relative_files(dir: &Path) -> anyhow::Result<Vec<String>> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d)? {
            let p = e?.path();
            if p.is_dir() {
                stack.push(p);
            } else if let Ok(rel) = p.strip_prefix(dir) {
                let rel: Vec<String> = rel
                    .components()
                    .map(|c| c.as_os_str().to_string_lossy().into_owned())
                    .collect();
                out.push(rel.join("/"));
            }
        }
    }
    out.retain(|f| f != MANIFEST);
    out.sort();
    Ok(out)
}

/// The files a previous run listed (none when there is no readable manifest).
fn read_manifest(out: &Path) -> Vec<String> {
    let Ok(text) = std::fs::read_to_string(out.join(MANIFEST)) else {
        return Vec::new();
    };
    let v: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
    v["files"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|f| f.as_str())
                .filter(|f| is_plain(f))
                .map(String::from)
                .collect()
        })
        .unwrap_or_default()
}

/// A relative path without `..` or a root: a manifest cannot name files outside `--out`.
fn is_plain(f: &str) -> bool {
    let p = Path::new(f);
    p.is_relative()
        && p.components()
            .all(|c| matches!(c, std::path::Component::Normal(_)))
}

/// Removes the staging directories in `parent` whose process is gone (a run killed there).
fn sweep_stale(parent: &Path) {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let pid = name.strip_prefix(PREFIX).and_then(|r| r.split('-').next());
        if let Some(pid) = pid
            && !Path::new("/proc").join(pid).exists()
        {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manifest_paths_stay_inside() {
        assert!(is_plain("a/b.png"));
        assert!(!is_plain("../x") && !is_plain("/etc/passwd") && !is_plain("a/../../b"));
    }
}
