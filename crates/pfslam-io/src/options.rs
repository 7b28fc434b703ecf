//! The options of every recording reader: [`ReaderOptions`], the `[input]` section of the
//! configuration (declared in the core, `pfslam::sensors::reader_options`), and the CARMEN
//! reader's options derived from them.

use super::carmen::CarmenOptions;
pub use pfslam::sensors::reader_options::{BeamGeometry, CarmenLaser, ReaderOptions};

impl CarmenOptions {
    /// The CARMEN reader's options of the `[input]` section.
    pub fn from_reader(options: &ReaderOptions) -> CarmenOptions {
        CarmenOptions {
            laser: options.carmen_laser,
            range_max_m: options
                .range_max_m
                .unwrap_or(CarmenOptions::default().range_max_m),
            strict: options.strict,
        }
    }
}
