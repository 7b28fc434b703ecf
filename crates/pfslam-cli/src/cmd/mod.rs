//! One module per subcommand: its clap `Args` and its `run`.

/// `println!` for the commands' reports: a closed pipe (`pfslam run ... | head -1`) ends
/// the printing quietly instead of panicking, as Unix tools do.
macro_rules! say {
    () => {
        say!("")
    };
    ($($arg:tt)*) => {{
        let _ = $crate::cmd::print_stdout(&format!("{}\n", format_args!($($arg)*)));
    }};
}

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
pub mod interrupt;
pub mod live;
pub mod localize;
pub mod map;
pub mod observer;
pub mod output;
pub mod perturb;
pub mod print_config;
pub mod record;
pub mod report;
pub mod resume;
pub mod run;
pub mod simulate;
pub mod texture;
pub mod thinned;

/// Set when standard output carries data (`run --poses-out -`): the messages go to standard
/// error then.
pub static MESSAGES_TO_STDERR: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);

/// Writes `text` to standard output (standard error when it carries data); a closed pipe
/// (`pfslam info X | head`) ends quietly, as Unix tools do.
pub fn print_stdout(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    if MESSAGES_TO_STDERR.load(std::sync::atomic::Ordering::Relaxed) {
        eprint!("{text}");
        return Ok(());
    }
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e.into()),
        _ => Ok(()),
    }
}
