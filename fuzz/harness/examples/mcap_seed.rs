//! Writes an MCAP fuzz seed with the library's own writer: the recording read from a small
//! ROS 1 bag or CARMEN log (see `fuzz/scripts/seeds.sh`), as CDR messages.
//! Usage: `mcap_seed IN OUT.mcap`.

use pfslam_io::options::ReaderOptions;
use pfslam_io::recording::read_recording;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args_os().skip(1);
    let (Some(input), Some(out)) = (args.next(), args.next()) else {
        return Err("usage: mcap_seed IN OUT.mcap".into());
    };
    let rec = read_recording(&PathBuf::from(input), &ReaderOptions::default())?;
    pfslam_io::mcap::write_mcap(&PathBuf::from(out), &rec, &ReaderOptions::default())?;
    Ok(())
}
