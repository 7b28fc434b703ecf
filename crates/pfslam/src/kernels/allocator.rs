//! The C library's allocator, set for a long run.

/// Makes glibc's `malloc` serve every block of 128 KiB or more with a mapping of its own,
/// returned to the system when freed. By default glibc raises that threshold to the size of
/// each large block freed, so that later large transient buffers (a consolidated window's
/// scans, its keyframes' points, the loop search's point fields) come from the heap, where
/// the long-lived blocks between them keep the freed space from being returned: the resident
/// memory of a long run then grows although its live heap does not (decision 0062). A
/// program calls this once, before it starts threads; elsewhere than glibc it does nothing.
pub fn unmap_large_blocks() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` sets one allocator parameter and touches no memory of the caller.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, LARGE_BLOCK_BYTES);
    }
}

/// glibc's own initial threshold.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const LARGE_BLOCK_BYTES: libc::c_int = 128 * 1024;
