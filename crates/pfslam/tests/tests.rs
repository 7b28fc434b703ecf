//! The library's integration tests: one binary (link time matters on 2 cores), one module per
//! area.

mod acceptance;
mod common;
mod consolidation;
mod eval;
mod field_cache;
mod filter;
mod graph;
mod localize;
mod map;
mod map_batches;
mod motion;
mod online;
mod pipeline;
mod rbpf;
mod readers;
mod readers_streamed;
mod session;
mod ucsd;
