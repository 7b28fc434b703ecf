//! The crate's `unsafe` code, and nowhere else (`#![deny(unsafe_code)]` at the crate root,
//! allowed on this module only): the LiDAR rows' vector parser ([`ranges`], its AVX2 code
//! in `ranges/x86.rs`, chosen by `pfslam::kernels::cpu`) and the recordings' memory maps
//! ([`memory_map`]). Every `unsafe` block says why it is sound in a `// SAFETY:` comment.

pub(crate) mod memory_map;
pub(crate) mod ranges;
