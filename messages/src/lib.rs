//! The wire contract of the pipeline: the message type of every topic, the
//! topic table, how services are named and opened, and the stamp clock.
//!
//! Every type is `#[repr(C)]`, [`iceoryx2::prelude::ZeroCopySend`] with a versioned type name,
//! of fixed capacity, and laid out without implicit padding (checked by the
//! size assertions below). Stereo frames travel as a `[u8]` slice (left
//! image then right image) with a [`FrameHeader`] user header.
//!
//! Every topic is declared once, in the [`topics`] table, as a marker type
//! that ports are typed by. Each topic is a publish-subscribe service
//! [`service::name`] plus an event service: publishers notify after sending,
//! and subscribers sleep until notified, so nothing polls. The prefix keeps
//! tests and parallel pipelines apart. The processes' side of it (the bus,
//! journals, stats, traces) is the `runtime` crate's.
//!
//! ```
//! use messages::{JointState, topics::{SmallTopic, Topic}};
//! assert_eq!(messages::topics::JointState::NAME, "joint_state");
//! assert_eq!(messages::service::name("demo", "joint_state"), "mirror/demo/joint_state");
//! # let _ = JointState::default();
//! ```

pub mod service;
pub mod topics;
mod types;

pub use types::*;

/// `text` with control characters (newlines included) escaped, so that an
/// error quoting text from a file or the network stays on one line.
pub fn one_line(text: &str) -> String {
    text.chars()
        .flat_map(|c| {
            let escaped: Vec<char> = if c.is_control() {
                c.escape_default().collect()
            } else {
                vec![c]
            };
            escaped
        })
        .collect()
}

/// CLOCK_MONOTONIC in nanoseconds: the one clock every stage stamps with,
/// comparable across processes on this machine.
#[allow(unsafe_code)]
pub fn now_ns() -> i64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

/// Wall-clock time (`CLOCK_REALTIME`), ns since the epoch.
pub fn wall_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

/// How far the wall clock is ahead of [`now_ns`]'s monotonic clock now, ns:
/// what maps our stamps to wall-clock time (ROS stamps, recordings'
/// exports) at this moment.
pub fn wall_minus_monotonic_ns() -> i64 {
    let before = now_ns();
    let wall = wall_ns();
    let after = now_ns();
    wall - (before + (after - before) / 2)
}
