//! The library's integration tests: one binary (link time matters on 2 cores), one module per
//! area.

mod common;
mod motion;
mod stereo;
mod ucsd;
