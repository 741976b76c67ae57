//! Whether the stages every sample waits for may run at real-time
//! priority.
//!
//! On two cores the recorder's compression, the camera's moving frames and
//! the tracker's periodic full scans share the CPU with the stages a frame
//! goes through; at normal priority (even with the recorder niced) a frame
//! now and then waits behind them, and the frame-to-sample tail grows to
//! tens of milliseconds. `SCHED_FIFO` runs the stages on the sample's path
//! before every normally scheduled process whenever they have work, each
//! further down the path above the ones before it (see
//! [`stages::StageArgs::sample_path_depth`]); they block between
//! frames, so the others keep the rest of the CPU (and the kernel keeps 5%
//! of each second for them whatever happens).

/// The base priority of the stages on the sample's path: `priority` when it
/// is not 0 and this process may set it (and the priorities above it up to
/// the highest stage's rank), else `None`, saying why on stderr.
pub fn realtime(priority: u8) -> Option<u8> {
    if priority == 0 {
        return None;
    }
    // The highest [`stages::StageArgs::sample_path_depth`] of any stage.
    let highest_rank = stages::StageArgs::examples()
        .iter()
        .filter_map(stages::StageArgs::sample_path_depth)
        .max()
        .unwrap_or(0);
    let highest = priority.saturating_add(highest_rank);
    match permitted(highest) {
        Ok(()) => Some(priority),
        Err(e) => {
            eprintln!(
                "pipeline: warning: real-time priorities {priority}-{highest} not allowed ({e}): the \
                 stages every sample waits for run at normal priority, and the frame-to-sample \
                 latency has a longer tail on a busy machine (allow them with root, CAP_SYS_NICE \
                 or `ulimit -r {highest}`; or set realtime_priority = 0)"
            );
            None
        }
    }
}

/// Tries `SCHED_FIFO` at `priority` on a thread of its own, which then ends:
/// the launcher's own threads keep their scheduling.
fn permitted(priority: u8) -> std::io::Result<()> {
    std::thread::spawn(move || runtime::realtime::fifo_this_thread(priority))
        .join()
        .unwrap_or_else(|_| Err(std::io::Error::other("the probe thread panicked")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_probe_leaves_the_launchers_own_scheduling_alone() {
        assert_eq!(realtime(0), None, "0 asks for nothing");
        let policy = || runtime::stats::Scheduling::of_this_thread().unwrap().policy;
        let before = policy();
        let given = realtime(10);
        assert_eq!(policy(), before, "the probe changed the caller's policy");
        // What it answers is what the system allows for the highest of the
        // priorities.
        assert_eq!(given.is_some(), permitted(15).is_ok());
    }
}
