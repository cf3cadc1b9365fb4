//! Optional real-time set-up of the control thread: SCHED_FIFO, locked memory, a pinned core.
//! Each step that the system refuses (no CAP_SYS_NICE, RLIMIT_MEMLOCK, …) is reported and skipped:
//! the loop still runs, with the jitter the histogram then shows.

#![allow(unsafe_code, reason = "two POSIX calls with plain-value arguments")]

/// What the set-up achieved, step by step.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RealtimeReport {
    /// One line per step: what was asked and what happened.
    pub steps: Vec<String>,
}

/// Puts the calling thread under SCHED_FIFO at `priority`, locks all memory, pins it to `cpu`.
pub fn setup(priority: i32, cpu: Option<usize>) -> RealtimeReport {
    let mut steps = Vec::new();
    steps.push(match firmware_bridge::time::set_fifo_priority(priority) {
        Ok(()) => format!("SCHED_FIFO priority {priority}: ok"),
        Err(e) => format!("SCHED_FIFO priority {priority}: refused ({e}); running with normal scheduling"),
    });
    // SAFETY: flags only.
    let r = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    steps.push(if r == 0 {
        "mlockall: ok".to_owned()
    } else {
        format!(
            "mlockall: refused ({}); pages may fault in the loop",
            std::io::Error::last_os_error()
        )
    });
    if let Some(cpu) = cpu {
        // SAFETY: a zeroed cpu_set_t is a valid empty set; CPU_SET writes inside it.
        let r = unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(cpu, &mut set);
            libc::sched_setaffinity(0, size_of::<libc::cpu_set_t>(), &set)
        };
        steps.push(if r == 0 {
            format!("pinned to CPU {cpu}: ok")
        } else {
            format!("pin to CPU {cpu}: refused ({})", std::io::Error::last_os_error())
        });
    }
    RealtimeReport { steps }
}

/// SCHED_FIFO priority of the bus threads: above the loop's, since a bus cycle that misses its
/// slot is a stale joint, and a policy tick can wait a few hundred microseconds.
pub const BUS_PRIORITY: i32 = 85;

/// Real-time set-up of a bus thread (run first on each, see `BusRobot::parallel_with`):
/// SCHED_FIFO at [`BUS_PRIORITY`]; a refusal is logged and the thread runs on normally.
pub fn bus_thread() {
    if let Err(e) = firmware_bridge::time::set_fifo_priority(BUS_PRIORITY) {
        tracing::warn!("bus thread: SCHED_FIFO priority {BUS_PRIORITY} refused ({e}); normal scheduling");
    }
}
