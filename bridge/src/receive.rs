//! The receiving side: takes zenoh's deliveries from a bounded queue,
//! admits what opens, comes in order and has stamps that can be, moves its
//! times onto this host's clock and publishes it here.

use std::collections::HashMap;
use std::sync::atomic::AtomicBool;

use messages::now_ns;
use messages::topics::TopicId;
use runtime::{AnyPublisher, Bus, Rejections};

use crate::counters::Counters;
use crate::envelope;
use crate::error::BridgeError;
use crate::offsets::Clocks;
use crate::options::Options;
use crate::{STAMP_SLACK_NS, TICK, any_set};

/// The receiving side: until one of `stops`.
pub(crate) fn receive(
    options: &Options,
    queue: crossbeam_channel::Receiver<(TopicId, Vec<u8>)>,
    counters: &Counters,
    clocks: &Clocks<'_>,
    stops: &[&AtomicBool],
) -> Result<(), BridgeError> {
    let bus = Bus::new(&options.prefix, "bridge_receive")?.declared(runtime::Ports {
        subscribes: &[],
        publishes: &options.receive,
    });
    // Publishers made as their topics' first messages come (a frame
    // publisher is sized by its first frame).
    let mut publishers: Vec<Option<AnyPublisher>> = (0..TopicId::COUNT).map(|_| None).collect();
    // The last sequence number from each sender on each topic.
    let mut last: HashMap<(String, TopicId), u64> = HashMap::new();
    let mut rejections = Rejections::default();
    let mut n = 0u64;
    while !any_set(stops) {
        let (topic, bytes) = match queue.recv_timeout(TICK) {
            Ok(delivery) => delivery,
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => continue,
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
        };
        n += 1;
        let mut scratch = Vec::new();
        let checked = admit(topic, &bytes, &mut scratch, &mut last, clocks, counters);
        let message = match checked {
            Ok(message) => message,
            Err(why) => {
                Counters::add(&counters.refused, 1);
                rejections.reject("message from the link", n, &why.to_string());
                continue;
            }
        };
        let publisher = match &mut publishers[topic.index()] {
            Some(p) => p,
            slot => slot.insert(
                AnyPublisher::new(&bus, topic, bytes.len())
                    .map_err(|source| BridgeError::Publish { topic, source })?,
            ),
        };
        publisher.publish(&message)?;
        Counters::add(&counters.received[topic.index()], 1);
    }
    Ok(())
}

/// Opens an envelope, checks its order and stamps, counts what the sender
/// numbered and never came, and moves the message's times onto this host's
/// clock; the error is one line naming what is wrong.
fn admit<'a>(
    topic: TopicId,
    bytes: &'a [u8],
    scratch: &'a mut Vec<u8>,
    last: &mut HashMap<(String, TopicId), u64>,
    clocks: &Clocks<'_>,
    counters: &Counters,
) -> Result<messages::topics::Message<'a>, Refusal> {
    let opened = envelope::open(topic, bytes, scratch)?;
    let from = opened.from;
    let seen = last.entry((from.sender.to_string(), topic)).or_insert(0);
    if from.seq <= *seen {
        return Err(Refusal::OutOfOrder {
            topic,
            seq: from.seq,
            sender: from.sender.to_string(),
            last: *seen,
        });
    }
    // The first message heard from a sender sets where its count starts.
    if *seen > 0 && from.seq > *seen + 1 {
        Counters::add(&counters.lost[topic.index()], from.seq - *seen - 1);
        tracing::debug!(
            topic = topic.name(),
            sender = from.sender,
            after = *seen,
            next = from.seq,
            "a gap in what the sender numbered"
        );
    }
    *seen = from.seq;
    let mut message = opened.message;
    let (offset, uncertainty_ns) = clocks
        .offset(from.sender, message.stamp_ns())
        .ok_or_else(|| Refusal::NoClockOffset(from.sender.to_string()))?;
    message.shift_clock(offset.ahead_ns.saturating_neg());
    let now = now_ns();
    let ahead = message.stamp_ns().saturating_sub(now);
    if ahead > uncertainty_ns.saturating_add(STAMP_SLACK_NS) {
        return Err(Refusal::StampAhead {
            topic,
            ahead_ns: ahead,
            uncertainty_ns,
        });
    }
    let sent_here = from.sent_ns.saturating_sub(offset.ahead_ns);
    let mut stats = counters.stats.lock().unwrap_or_else(|p| p.into_inner());
    stats.record("link", now.saturating_sub(sent_here));
    stats.record("clock_uncertainty", uncertainty_ns);
    Ok(message)
}

/// Why a message from the link is refused: one line, logged.
#[derive(Debug, thiserror::Error)]
pub(crate) enum Refusal {
    /// Its envelope does not open.
    #[error(transparent)]
    Open(#[from] envelope::OpenError),
    /// Its sender numbered it at or before the last one taken from it.
    #[error(
        "{} message {seq} from {sender} after its message {last} (repeated or out of order)",
        .topic.name()
    )]
    OutOfOrder {
        topic: TopicId,
        seq: u64,
        sender: String,
        last: u64,
    },
    /// Its sender (by zenoh id) has no clock offset.
    #[error("no clock offset to {0}: it does not answer round trips")]
    NoClockOffset(String),
    /// Its stamp, on this host's clock, is further ahead than the offset's
    /// uncertainty and [`STAMP_SLACK_NS`] allow.
    #[error(
        "{} stamp {:.3} s ahead of this host's clock (offset uncertainty {:.0} us)",
        .topic.name(),
        *.ahead_ns as f64 * 1e-9,
        *.uncertainty_ns as f64 * 1e-3
    )]
    StampAhead {
        topic: TopicId,
        ahead_ns: i64,
        uncertainty_ns: i64,
    },
}
