//! Message types of every topic and the iceoryx2 plumbing the stages share.
//!
//! Every type is `#[repr(C)]`, [`iceoryx2::prelude::ZeroCopySend`] with a versioned type name,
//! of fixed capacity, and laid out without implicit padding (checked by the
//! size assertions below). Stereo frames travel as a `[u8]` slice (left
//! image then right image) with a [`FrameHeader`] user header.
//!
//! Every topic is declared once, in the [`topics`] table, as a marker type
//! that ports are typed by. Each topic is a publish-subscribe service `<prefix>/<topic>` plus an event
//! service `<prefix>/<topic>/event`: publishers notify after sending, and
//! subscribers sleep in a [`iceoryx2::waitset::WaitSet`] until notified, so
//! nothing polls. The prefix keeps tests and parallel pipelines apart.
//!
//! ```no_run
//! use messages::{Bus, JointState, topics};
//! let bus = Bus::new("demo", "example")?;
//! let publisher = bus.publisher::<topics::JointState>()?;
//! publisher.send(JointState::default())?;
//! # Ok::<(), messages::BusError>(())
//! ```

mod any_port;
mod bus;
pub mod journal;
pub mod realtime;
pub mod stats;
pub mod topics;
pub mod trace;
mod types;

pub use any_port::{AnyPublisher, AnySubscriber, Taken};
pub use bus::{
    Bus, BusError, EVENT_SUFFIX, FRAME_BUFFER, FramePublisher, FrameSubscriber, MAX_PORTS,
    OpenServices, Ports, Publisher, SMALL_BUFFER, Subscriber, Wake, remove_dead_nodes,
    service_name,
};
pub use types::*;

/// Counts the messages a stage drops as malformed and logs why: the first
/// ten, then every hundredth, so that a flood of bad messages cannot flood
/// the log.
#[derive(Debug, Default)]
pub struct Rejections {
    count: u64,
}

impl Rejections {
    /// Counts and (maybe) logs one dropped `what` (e.g. "frame") `seq`.
    pub fn reject(&mut self, what: &str, seq: u64, why: &str) {
        self.count += 1;
        if self.count <= 10 || self.count.is_multiple_of(100) {
            tracing::warn!(seq, rejected = self.count, "dropping a {what}: {why}");
        }
    }

    /// Messages dropped so far.
    pub fn count(&self) -> u64 {
        self.count
    }
}

/// Keeps a stream's stamps moving forward: a message stamped at or before
/// the last one taken is refused, unless [`StampOrder::RESYNC_AFTER`] in a
/// row are, which means the last one taken was stamped wrong (far ahead)
/// and must not hold back everything after it.
#[derive(Debug)]
pub struct StampOrder {
    last: i64,
    behind_in_a_row: u32,
}

impl Default for StampOrder {
    fn default() -> Self {
        Self {
            last: i64::MIN,
            behind_in_a_row: 0,
        }
    }
}

impl StampOrder {
    /// Refused messages in a row after which the stream is taken as right.
    pub const RESYNC_AFTER: u32 = 3;

    /// Takes `stamp`, or says why not.
    pub fn check(&mut self, stamp: i64) -> Result<(), String> {
        if stamp <= self.last && self.behind_in_a_row < Self::RESYNC_AFTER {
            self.behind_in_a_row += 1;
            return Err(format!("stamp {stamp} not after {}", self.last));
        }
        self.behind_in_a_row = 0;
        self.last = stamp;
        Ok(())
    }
}

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

/// Logs to stderr, filtered by `RUST_LOG` (default `info`), in colour only
/// on a terminal (stage logs usually go to a file, `stages.log`); with
/// `MIRROR_TRACE_DIR` set, also writes every span as a trace event (see
/// [`trace`]). `name` names the process in the trace.
pub fn init_logging(name: &str) {
    use tracing_subscriber::prelude::*;
    stats::mark_process_start();
    let fmt = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        );
    let mut trace_error = None;
    let chrome = std::env::var_os(trace::TRACE_DIR_ENV).and_then(|dir| {
        trace::ChromeLayer::create(std::path::Path::new(&dir), name)
            .map_err(|e| {
                trace_error = Some(format!("{}: {e}", std::path::Path::new(&dir).display()))
            })
            .ok()
    });
    let chrome =
        chrome.map(|l| l.with_filter(tracing_subscriber::filter::filter_fn(|meta| meta.is_span())));
    tracing_subscriber::registry().with(fmt).with(chrome).init();
    if let Some(e) = trace_error {
        tracing::warn!("no trace: {e}");
    }
}

/// Runs a stage's `main`: logs to stderr (`RUST_LOG`, default `info`), then
/// maps an error to one line `<name>: error: ...` and exit code 1.
pub fn stage_main(name: &str, run: impl FnOnce() -> anyhow::Result<()>) -> std::process::ExitCode {
    init_logging(name);
    let result = run();
    trace::flush();
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{name}: error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::StampOrder;

    #[test]
    fn stamp_order_refuses_the_past_and_recovers_from_a_stamp_far_ahead() {
        let mut order = StampOrder::default();
        assert!(order.check(10).is_ok());
        assert!(order.check(10).is_err(), "a repeated stamp");
        assert!(order.check(5).is_err(), "going back");
        assert!(order.check(20).is_ok());
        // One message stamped far ahead, then the real stream.
        assert!(order.check(1_000_000).is_ok());
        assert!(order.check(30).is_err());
        assert!(order.check(40).is_err());
        assert!(order.check(50).is_err());
        assert!(order.check(60).is_ok(), "three in a row: the stream wins");
        assert!(order.check(70).is_ok());
    }
}
