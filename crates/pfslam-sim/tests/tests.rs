//! The simulator's integration tests: one binary (link time matters on 2 cores), one module
//! per area.

mod camera;
mod sim;
mod sim_stereo;
