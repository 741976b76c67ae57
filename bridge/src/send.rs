//! The sending side: takes the sent topics from shared memory once a
//! receiver of each is on the link, and puts them on it, small messages
//! first.

use std::cell::Cell;
use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use messages::now_ns;
use messages::topics::TopicId;
use runtime::{AnySubscriber, Bus};
use zenoh::Wait;
use zenoh::qos::{CongestionControl, Priority};

use crate::counters::Counters;
use crate::envelope;
use crate::error::BridgeError;
use crate::options::Options;
use crate::{ROUND_TRIP_WITHIN, TICK, any_set};

/// The sending side: until a signal or one of `stops`.
pub(crate) fn send(
    options: &Options,
    session: &zenoh::Session,
    zid: &str,
    counters: &Counters,
    stops: &[&AtomicBool],
) -> Result<(), BridgeError> {
    let bus = Bus::new(&options.prefix, "bridge_send")?.declared(runtime::Ports {
        subscribes: &options.send,
        publishes: &[],
    });
    let mut publishers = Vec::new();
    for &topic in &options.send {
        let (congestion, priority) = if topic.carries_frames() {
            (CongestionControl::Drop, Priority::DataLow)
        } else {
            (CongestionControl::Block, Priority::Data)
        };
        let publisher = session
            .declare_publisher(options.key(topic))
            .congestion_control(congestion)
            .priority(priority)
            .wait()
            .map_err(|e| BridgeError::zenoh(format!("publishing {}", options.key(topic)), e))?;
        publishers.push((topic, publisher));
    }
    // Nothing is taken from shared memory before someone receives it. Frames
    // are droppable: a side that wants none (a workstation that does not
    // record) does not hold the other topics back; they go unheard, counted.
    let small_sent = publishers.iter().any(|(t, _)| !t.carries_frames());
    let awaited = |t: &TopicId| !(small_sent && t.carries_frames());
    let mut waiting_since = Instant::now();
    while let Some((topic, _)) = publishers.iter().find(|(t, p)| awaited(t) && !heard(p)) {
        if any_set(stops) || !bus.sleep(Duration::from_millis(10)) {
            return Ok(());
        }
        if waiting_since.elapsed() > Duration::from_secs(10) {
            tracing::info!("still waiting for a receiver of {}", options.key(*topic));
            waiting_since = Instant::now();
        }
    }
    for (topic, _) in &publishers {
        check_layouts(options, session, *topic)?;
    }
    let taps = publishers
        .iter()
        .map(|(topic, _)| Ok((AnySubscriber::new(&bus, *topic)?, Cell::new(0u64))))
        .collect::<Result<Vec<_>, BridgeError>>()?;
    if !taps.is_empty() {
        tracing::info!("every sent topic has a receiver: sending");
    }
    let (small_out, small) = crossbeam_channel::bounded::<Outgoing>(SEND_QUEUE_SMALL);
    let (frames_out, frames) = crossbeam_channel::bounded::<Outgoing>(SEND_QUEUE_FRAMES);
    let put_failed = AtomicBool::new(false);
    std::thread::scope(|s| {
        let putting = s.spawn(|| {
            let result = put(
                &publishers,
                options.frame_encoding,
                zid,
                small,
                frames,
                counters,
            );
            put_failed.store(result.is_err(), Ordering::Relaxed);
            result
        });
        let listeners: Vec<_> = taps.iter().map(|(tap, _)| tap.listener()).collect();
        let taken = bus
            .wake()?
            .run(&listeners, Some(TICK), || -> Result<_, BridgeError> {
                for (tap, seq) in &taps {
                    let topic = tap.topic();
                    let queue = if topic.carries_frames() {
                        &frames_out
                    } else {
                        &small_out
                    };
                    while let Some(taken) = tap.take()? {
                        seq.set(seq.get() + 1);
                        let outgoing = Outgoing {
                            topic,
                            seq: seq.get(),
                            bytes: taken.bytes,
                        };
                        if queue.try_send(outgoing).is_err() {
                            Counters::add(&counters.dropped[topic.index()], 1);
                        }
                    }
                }
                Ok(if any_set(stops) || put_failed.load(Ordering::Relaxed) {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                })
            });
        // The putting side sends what is queued, then ends.
        drop((small_out, frames_out));
        let put = putting
            .join()
            .map_err(|_| BridgeError::Panicked("putting"))?;
        taken.and(put)
    })
}

/// Asks every receiving bridge on the link which layout it takes `topic`
/// in; one that differs from this side's is an error naming both (the two
/// hosts run builds that do not agree: nothing of the topic would open).
fn check_layouts(
    options: &Options,
    session: &zenoh::Session,
    topic: TopicId,
) -> Result<(), BridgeError> {
    let ours = topic.layout().type_name;
    let replies = session
        .get(options.layout_key(topic, "*"))
        .timeout(ROUND_TRIP_WITHIN)
        .wait()
        .map_err(|e| {
            BridgeError::zenoh(
                format!("asking the receivers' layouts of {}", topic.name()),
                e,
            )
        })?;
    while let Ok(reply) = replies.recv() {
        let Ok(sample) = reply.result() else { continue };
        let theirs = String::from_utf8_lossy(&sample.payload().to_bytes()).into_owned();
        if theirs != ours {
            let receiver = sample.key_expr().as_str().rsplit('/').next().unwrap_or("?");
            return Err(BridgeError::LayoutMismatch {
                topic,
                ours,
                receiver: receiver.to_string(),
                theirs,
            });
        }
    }
    Ok(())
}

/// Whether a receiver of `publisher`'s key is on the link.
fn heard(publisher: &zenoh::pubsub::Publisher<'_>) -> bool {
    publisher
        .matching_status()
        .wait()
        .is_ok_and(|status| status.matching())
}

/// A message taken from shared memory, waiting for the link.
struct Outgoing {
    topic: TopicId,
    /// The sender's count of messages on `topic`.
    seq: u64,
    bytes: Vec<u8>,
}

/// Small messages that may wait for the link (16 s of joint states at
/// 250 Hz): a link that stalls for a moment (a TCP retransmission, a
/// reconnection) loses none of them. Past it they are dropped and counted.
const SEND_QUEUE_SMALL: usize = 4096;

/// Frames that may wait for the link: a frame late by more is stale.
const SEND_QUEUE_FRAMES: usize = 4;

/// Puts what is queued on the link, small messages first, until both
/// queues are closed and empty.
fn put(
    publishers: &[(TopicId, zenoh::pubsub::Publisher<'_>)],
    frame_encoding: envelope::Encoding,
    zid: &str,
    small: crossbeam_channel::Receiver<Outgoing>,
    frames: crossbeam_channel::Receiver<Outgoing>,
    counters: &Counters,
) -> Result<(), BridgeError> {
    let publisher = |topic: TopicId| {
        publishers
            .iter()
            .find(|(t, _)| *t == topic)
            .map(|(_, p)| p)
            .expect("a publisher per sent topic")
    };
    let encoding = |topic: TopicId| {
        if topic.carries_frames() {
            frame_encoding
        } else {
            envelope::Encoding::Raw
        }
    };
    let (mut small_open, mut frames_open) = (true, true);
    loop {
        let out = if let Ok(out) = small.try_recv() {
            out
        } else {
            let mut select = crossbeam_channel::Select::new();
            let small_index = small_open.then(|| select.recv(&small));
            if frames_open {
                select.recv(&frames);
            }
            if !(small_open || frames_open) {
                break;
            }
            let op = select.select();
            let is_small = Some(op.index()) == small_index;
            match op.recv(if is_small { &small } else { &frames }) {
                Ok(out) => out,
                Err(_) if is_small => {
                    small_open = false;
                    continue;
                }
                Err(_) => {
                    frames_open = false;
                    continue;
                }
            }
        };
        let publisher = publisher(out.topic);
        if !heard(publisher) {
            tracing::debug!(
                topic = out.topic.name(),
                seq = out.seq,
                "put with no receiver on the link"
            );
            Counters::add(&counters.unheard[out.topic.index()], 1);
        }
        let from = envelope::From {
            sender: zid,
            seq: out.seq,
            sent_ns: now_ns(),
        };
        publisher
            .put(envelope::seal(
                out.topic,
                from,
                encoding(out.topic),
                &out.bytes,
            ))
            .wait()
            .map_err(|e| BridgeError::zenoh(format!("sending on {}", out.topic.name()), e))?;
        Counters::add(&counters.sent[out.topic.index()], 1);
    }
    Ok(())
}
