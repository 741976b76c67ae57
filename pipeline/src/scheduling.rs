//! Whether the stages every sample waits for may run at real-time
//! priority.
//!
//! On two cores the recorder's compression shares the CPU with the
//! stages between frame and sample; at normal priority (even with the
//! recorder niced) a frame now and then waits behind it, and the
//! frame-to-sample tail grows to tens of milliseconds. `SCHED_FIFO` runs
//! the stages on the sample's path before every normally scheduled process
//! whenever they have work; they block between frames, so the others keep
//! the rest of the CPU (and the kernel keeps 5% of each second for them
//! whatever happens).

/// The base priority of the stages on the sample's path: `priority` when it
/// is not 0 and this process may set it (and two above, for the stages
/// further down the path), else `None`, saying why on stderr.
pub fn realtime(priority: u8) -> Option<u8> {
    if priority == 0 {
        return None;
    }
    match permitted(priority.saturating_add(2)) {
        Ok(()) => Some(priority),
        Err(e) => {
            eprintln!(
                "pipeline: warning: real-time priority {priority} not allowed ({e}): the stages \
                 every sample waits for run at normal priority, and the frame-to-sample latency \
                 has a longer tail on a busy machine (allow it with root, CAP_SYS_NICE or \
                 `ulimit -r {priority}`; or set realtime_priority = 0)"
            );
            None
        }
    }
}

/// Tries `SCHED_FIFO` at `priority` on a thread of its own, which then ends:
/// the launcher's own threads keep their scheduling.
fn permitted(priority: u8) -> std::io::Result<()> {
    std::thread::spawn(move || {
        let param = libc::sched_param {
            sched_priority: i32::from(priority),
        };
        // SAFETY: sched_setscheduler(2) on the calling thread (pid 0) with a
        // valid parameter; the thread ends right after.
        #[allow(unsafe_code)]
        let result = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
        if result == -1 {
            Err(std::io::Error::last_os_error())
        } else {
            Ok(())
        }
    })
    .join()
    .unwrap_or_else(|_| Err(std::io::Error::other("the probe thread panicked")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_asks_for_nothing_and_an_allowed_priority_is_given() {
        assert_eq!(realtime(0), None);
        // Whether this machine allows it decides the answer, not the test:
        // the answer must agree with what the system says.
        assert_eq!(realtime(10).is_some(), permitted(10).is_ok());
    }
}
