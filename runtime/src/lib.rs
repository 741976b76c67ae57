//! What every stage process runs on: the iceoryx2 bus with typed ports
//! ([`Bus`], [`Wake`]), ports for any topic ([`AnyPublisher`],
//! [`AnySubscriber`]), crash-safe journals, stats, traces, real-time
//! scheduling, and a stage's `main` ([`stage_main`]).
//!
//! ```no_run
//! use messages::{JointState, topics};
//! use runtime::Bus;
//! let bus = Bus::new("demo", "example")?;
//! let publisher = bus.publisher::<topics::JointState>()?;
//! publisher.send(JointState::default())?;
//! # Ok::<(), runtime::BusError>(())
//! ```

mod any_port;
mod bus;
pub mod journal;
pub mod realtime;
pub mod stats;
pub mod trace;

pub use any_port::{AnyPublisher, AnySubscriber, Taken};
pub use bus::{
    Bus, BusError, FramePublisher, FrameSubscriber, OpenServices, Ports, Publisher, Subscriber,
    Wake, remove_dead_nodes,
};

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
    pub fn check(&mut self, stamp: i64) -> Result<(), StampBehind> {
        if stamp <= self.last && self.behind_in_a_row < Self::RESYNC_AFTER {
            self.behind_in_a_row += 1;
            return Err(StampBehind {
                stamp,
                last: self.last,
            });
        }
        self.behind_in_a_row = 0;
        self.last = stamp;
        Ok(())
    }
}

/// A stamp [`StampOrder::check`] refused: not after the last one taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("stamp {stamp} not after {last}")]
pub struct StampBehind {
    /// The stamp refused, ns.
    pub stamp: i64,
    /// The last stamp taken, ns.
    pub last: i64,
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
/// maps an error to one line `<name>: error: ...` and exit code 1. The error
/// is printed with the alternate flag (`{e:#}`): an `anyhow::Error` prints
/// its whole chain of causes.
pub fn stage_main<E: std::fmt::Display>(
    name: &str,
    run: impl FnOnce() -> Result<(), E>,
) -> std::process::ExitCode {
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
