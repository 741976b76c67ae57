//! Publishing a recording back onto the bus, so that any subset of stages
//! can run on it: frames (and joint states) to re-run the tracker and the
//! mirror stage, or detections and joint states to re-run the mirror stage.
//!
//! Replay creates every service of its prefix *lossless* (see
//! [`runtime::Bus::lossless`]) before any stage starts: a full subscriber
//! buffer then makes the publisher wait instead of dropping, all the way
//! down the pipeline, so nothing is lost at any speed.

use std::time::{Duration, Instant};

use messages::topics::TopicId;
use runtime::{AnyPublisher, Bus, BusError};

use crate::reader::{ReadError, Recording};

pub use stages::replay::{Kind, Pace};

/// What to replay and how.
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    /// Pace.
    pub pace: Pace,
    /// Skip messages logged earlier than this many seconds after the first.
    pub start_s: f64,
    /// Wait (up to `wait_timeout`) until each replayed topic has this many
    /// subscribers before publishing.
    pub wait_subscribers: usize,
    /// How long to wait for subscribers.
    pub wait_timeout: Duration,
    /// Show a progress bar.
    pub progress: bool,
}

/// Why a replay could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The bus failed: opening it or a publisher, waiting for subscribers,
    /// publishing.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The services of the prefix could not be created (lossless) before
    /// the stages start.
    #[error(
        "replay must create the services of prefix `{prefix}` before the stages \
         start; is a live pipeline using this prefix?"
    )]
    Services {
        /// The pipeline prefix.
        prefix: String,
        /// Why the bus could not create them.
        #[source]
        source: BusError,
    },
    /// The recording could not be read.
    #[error(transparent)]
    Read(#[from] ReadError),
}

/// What a replay did.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ReplayStats {
    /// Messages published.
    pub published: u64,
    /// Recorded time span covered, s.
    pub recorded_seconds: f64,
    /// Wall time taken, s.
    pub wall_seconds: f64,
    /// Set if the file was damaged and replay stopped early.
    pub stopped_early: Option<String>,
}

impl ReplayStats {
    /// Recorded time per wall time.
    pub fn speed(&self) -> f64 {
        self.recorded_seconds / self.wall_seconds.max(1e-9)
    }
}

/// The lossless services of a replay and its publishers, created before
/// anything else.
pub struct ReplayBus {
    bus: Bus,
    topics: Vec<TopicId>,
    /// By [`TopicId::index`]; `None` for a topic not replayed.
    publishers: Vec<Option<AnyPublisher>>,
    _services: runtime::OpenServices,
}

impl ReplayBus {
    /// Creates every service of `prefix` lossless, and the publishers of
    /// `topics` (frames sized for `recording`). Do this before the stages
    /// start: they inherit the setting, and with overflow off iceoryx2 0.10
    /// can lose the first samples to a subscriber that came before its
    /// publisher (seen here as frames 4 and 5 missing in 1 of 4 replays).
    pub fn create(
        prefix: &str,
        recording: &Recording,
        topics: &[TopicId],
    ) -> Result<Self, ReplayError> {
        let bus = Bus::new(prefix, "replay")?.lossless();
        let services = bus.open_all().map_err(|source| ReplayError::Services {
            prefix: prefix.to_string(),
            source,
        })?;
        let publishers = TopicId::ALL
            .into_iter()
            .map(|t| {
                topics
                    .contains(&t)
                    .then(|| AnyPublisher::new(&bus, t, recording.contents().largest_frame_bytes))
                    .transpose()
            })
            .collect::<Result<_, BusError>>()?;
        Ok(Self {
            bus,
            topics: topics.to_vec(),
            publishers,
            _services: services,
        })
    }
}

/// Replays `recording` onto the replay bus. `stop` is polled between
/// messages (Ctrl-C).
pub fn replay(
    replay_bus: &ReplayBus,
    recording: &Recording,
    options: &ReplayOptions,
    stop: &dyn Fn() -> bool,
) -> Result<ReplayStats, ReplayError> {
    let bus = &replay_bus.bus;
    let topics = &replay_bus.topics;
    let waiting = Instant::now();
    for &t in topics {
        let left = options.wait_timeout.saturating_sub(waiting.elapsed());
        bus.wait_for_subscribers(t, options.wait_subscribers, left, stop)?;
    }
    let contents = recording.contents();
    let first = contents.time_range.map_or(0, |r| r.0);
    let start_at = first + (options.start_s.max(0.0) * 1e9) as u64;
    let total: u64 = topics
        .iter()
        .map(|t| contents.counts.get(t).copied().unwrap_or(0))
        .sum();
    let bar = if options.progress {
        indicatif::ProgressBar::new(total)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} messages ({per_sec})",
        )
        .expect("a valid template")
        .progress_chars("=> "),
    );
    let mut stats = ReplayStats::default();
    let began = Instant::now();
    let mut replay_origin: Option<u64> = None;
    let mut last_time = None;
    recording.for_each(|log_time, message| -> Result<bool, ReplayError> {
        if stop() {
            return Ok(false);
        }
        let Some(publisher) = &replay_bus.publishers[message.topic().index()] else {
            return Ok(true);
        };
        if log_time < start_at {
            return Ok(true);
        }
        let origin = *replay_origin.get_or_insert(log_time);
        let scale = match options.pace {
            Pace::Original => Some(1.0),
            Pace::Scaled(f) => Some(f),
            Pace::Lockstep => None,
        };
        if let Some(scale) = scale {
            let due = Duration::from_secs_f64(log_time.saturating_sub(origin) as f64 / 1e9 / scale);
            if let Some(wait) = due.checked_sub(began.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        publisher.publish(&message)?;
        stats.published += 1;
        last_time = Some(log_time);
        bar.inc(1);
        Ok(true)
    })?;
    bar.finish_and_clear();
    stats.wall_seconds = began.elapsed().as_secs_f64();
    stats.recorded_seconds = match (replay_origin, last_time) {
        (Some(a), Some(b)) => b.saturating_sub(a) as f64 / 1e9,
        _ => 0.0,
    };
    stats.stopped_early = contents.damage.as_ref().map(|d| {
        format!(
            "{}: readable up to {} messages, then: {}",
            recording.path().display(),
            d.after_messages,
            d.error
        )
    });
    Ok(stats)
}
