//! The likelihood field of a whole fixed map, for Monte Carlo localisation
//! ([`crate::localize`]): the particles are weighed in it, and the converged estimate is
//! refined by a climb in it.
//!
//! - `field`: per cell, the log-likelihood of a return ending there, from its distance to
//!   the nearest occupied cell (an exact Euclidean distance transform); sharp for tracking,
//!   broad for global localisation.
//! - `refine`: a pose moved to the best score of a whole scan by a hill climb.

mod field;
mod refine;

pub use field::*;
pub use refine::*;
