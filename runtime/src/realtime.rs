//! Real-time scheduling of one thread: the launcher runs the stages every
//! sample waits for at `SCHED_FIFO`, and the recorder's thread that takes
//! messages out of shared memory must keep up with them.

/// Puts the calling thread under `SCHED_FIFO` at `priority` (1 to 99).
/// Threads it starts afterwards inherit it; threads already running keep
/// their own scheduling.
pub fn fifo_this_thread(priority: u8) -> std::io::Result<()> {
    let param = libc::sched_param {
        sched_priority: i32::from(priority),
    };
    // SAFETY: sched_setscheduler(2) on the calling thread (pid 0) with a
    // valid parameter.
    #[allow(unsafe_code)]
    let result = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if result == -1 {
        Err(std::io::Error::last_os_error())
    } else {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy() -> String {
        crate::stats::Scheduling::of_this_thread().unwrap().policy
    }

    #[test]
    fn a_thread_put_under_fifo_is_scheduled_so_and_its_siblings_are_not() {
        let before = policy();
        let (result, inside) = std::thread::spawn(|| {
            let result = fifo_this_thread(5);
            (result, policy())
        })
        .join()
        .unwrap();
        match result {
            Ok(()) => assert_eq!(inside, "fifo"),
            Err(e) => assert_eq!(e.raw_os_error(), Some(libc::EPERM), "{e}"),
        }
        assert_eq!(policy(), before, "another thread's call changed this one");
        assert!(fifo_this_thread(0).is_err(), "0 is no FIFO priority");
    }
}
