//! Deterministic random streams for parallel work.
//!
//! Particles are split into fixed-size chunks (independent of the thread count); chunk `c`
//! draws from its own stream, the master generator `jump()`ed `c` times (2^128 draws apart,
//! so streams never overlap). Whichever thread runs a chunk, it sees the same numbers, so a
//! run is bit-identical with 1 or many threads.

use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// Particles per chunk: the unit of parallel work and of random streams. Fixed so results do
/// not depend on the machine; small enough to balance 100 particles over a few threads.
pub const CHUNK_PARTICLES: usize = 8;

/// The master generator and one stream per chunk of particles.
#[derive(Debug, Clone)]
pub struct FilterRng {
    /// Sequential draws (resampling); positioned after all chunk streams.
    pub master: Xoshiro256PlusPlus,
    /// One stream per chunk of [`CHUNK_PARTICLES`] particles.
    pub chunks: Vec<Xoshiro256PlusPlus>,
}

impl FilterRng {
    /// Streams for `particle_count` particles from `seed`.
    pub fn new(seed: u64, particle_count: usize) -> Self {
        let mut master = Xoshiro256PlusPlus::seed_from_u64(seed);
        let n_chunks = particle_count.div_ceil(CHUNK_PARTICLES);
        let mut chunks = Vec::with_capacity(n_chunks);
        for _ in 0..n_chunks {
            chunks.push(master.clone());
            master.jump();
        }
        FilterRng { master, chunks }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    #[test]
    fn streams_differ_and_repeat() {
        let mut a = FilterRng::new(7, 20);
        let mut b = FilterRng::new(7, 20);
        assert_eq!(a.chunks.len(), 3);
        let x: Vec<u64> = a.chunks.iter_mut().map(|r| r.next_u64()).collect();
        let y: Vec<u64> = b.chunks.iter_mut().map(|r| r.next_u64()).collect();
        assert_eq!(x, y);
        assert_ne!(x[0], x[1]);
        assert_ne!(a.master.next_u64(), x[0]);
    }
}
