//! Embeds the library's source files so `config::annotated_toml` can print each option's doc
//! comment next to it (`pfslam print-config`), whichever module declares the option.

use std::path::{Path, PathBuf};

fn collect(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            collect(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

fn main() {
    let manifest = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".into());
    let src = Path::new(&manifest).join("src");
    println!("cargo:rerun-if-changed={}", src.display());
    let mut files = Vec::new();
    collect(&src, &mut files);
    // Sorted so the generated file (and the doc lookup order) is reproducible.
    files.sort();
    let mut text = String::from("/// Every library source file, for doc-comment lookup.\n");
    text.push_str("pub static SOURCES: &[&str] = &[\n");
    for f in &files {
        println!("cargo:rerun-if-changed={}", f.display());
        text.push_str(&format!(
            "    include_str!({:?}),\n",
            f.display().to_string()
        ));
    }
    text.push_str("];\n");
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap_or_else(|_| ".".into()));
    if let Err(e) = std::fs::write(out.join("config_sources.rs"), text) {
        println!("cargo:warning=cannot write config_sources.rs: {e}");
    }
}
