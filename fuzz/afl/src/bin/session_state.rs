//! AFL++ entry of the `session_state` fuzz target (see `fuzz/harness`).

#[global_allocator]
static ALLOC: pfslam_fuzz_harness::CappedAlloc = pfslam_fuzz_harness::CappedAlloc;

fn main() {
    afl::fuzz!(|data: &[u8]| {
        pfslam_fuzz_harness::set_input_len(data.len());
        pfslam_fuzz_harness::session_state(data);
    });
}
