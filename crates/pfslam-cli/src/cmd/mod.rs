//! One module per subcommand: its clap `Args` and its `run`.

pub mod bench_e2e;
pub mod benchmark;
pub mod dataset;
pub mod dead_reckon;
pub mod demo;
pub mod eval;
pub mod experiment;
pub mod map;
pub mod print_config;
pub mod run;
pub mod simulate;
pub mod texture;
