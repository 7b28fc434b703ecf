//! A criterion measurement: the calling thread's CPU time (`/proc/thread-self/schedstat`,
//! Linux; 0 elsewhere). On a machine shared with other work it does not include the time
//! the thread waited for a core, so single-threaded kernels keep their figure under load.
//! The kernel refreshes a running thread's figure at scheduler ticks (a few ms), so use it
//! only for iterations of tens of milliseconds or more (the parse bench's whole files).

use criterion::measurement::{Measurement, ValueFormatter, WallTime};

/// CPU time of the calling thread (ns), from the scheduler's statistics.
pub struct ThreadCpuTime;

fn thread_cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(0)
}

impl Measurement for ThreadCpuTime {
    type Intermediate = u64;
    type Value = u64;
    fn start(&self) -> u64 {
        thread_cpu_ns()
    }
    fn end(&self, i: u64) -> u64 {
        thread_cpu_ns().saturating_sub(i)
    }
    fn add(&self, a: &u64, b: &u64) -> u64 {
        a + b
    }
    fn zero(&self) -> u64 {
        0
    }
    fn to_f64(&self, v: &u64) -> f64 {
        *v as f64
    }
    fn formatter(&self) -> &dyn ValueFormatter {
        // Nanoseconds, like wall time.
        static WALL: WallTime = WallTime;
        WALL.formatter()
    }
}
