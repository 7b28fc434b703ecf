//! One module per subcommand: its clap `Args` and its `run`.

pub mod bench_e2e;
pub mod benchmark;
pub mod corpus;
pub mod dataset;
pub mod dead_reckon;
pub mod demo;
pub mod eval;
pub mod experiment;
pub mod info;
pub mod input;
pub mod map;
pub mod output;
pub mod perturb;
pub mod print_config;
pub mod run;
pub mod simulate;
pub mod texture;

/// Writes `text` to standard output; a closed pipe (`pfslam info X | head`) ends quietly, as
/// Unix tools do.
pub fn print_stdout(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e.into()),
        _ => Ok(()),
    }
}
