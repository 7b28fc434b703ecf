//! Read-only memory maps of recording files (ROS 1 bags, MCAP).

use std::fs::File;

/// Maps `file` (opened for reading) into memory, read-only.
pub(crate) fn map_read_only(file: &File) -> std::io::Result<memmap2::Mmap> {
    // SAFETY: the map is read-only and the file was opened read-only; as with any memory
    // map, another process truncating or rewriting the file while it is read is outside
    // what a reader can guard against (then reads may fault or see the new bytes).
    unsafe { memmap2::Mmap::map(file) }
}
