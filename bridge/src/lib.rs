//! The bridge between hosts: carries chosen pipeline topics from this
//! host's shared memory to another host over zenoh, and others back.
//!
//! Each side runs one `bridge` process beside its stages. A topic it sends
//! is read from shared memory and put on the zenoh key
//! `<namespace>/<topic>`; a topic it receives is taken from that key and
//! published into shared memory under the local prefix, so that the stages
//! on either side are the same binaries as on one host. Every message
//! crosses in an [`envelope`] naming its layout; what does not open (bad
//! size, another layout, a frame whose header disagrees with its pixels)
//! is refused, counted and logged, never published.
//!
//! Stamps cross onto the receiving host's clock: each side answers round
//! trips on its [`clock`] key, and the receiving side moves every message's
//! times by the offset it estimates from them (see [`clock`]).
//!
//! Three threads: the sending one sleeps on the subscribers' events and puts
//! each message on the link; the receiving one takes zenoh's deliveries
//! from a bounded queue, checks them, moves their times and publishes them;
//! the clock one keeps the offsets to the senders fresh. Small messages are
//! sent reliably (zenoh blocks rather than drops them when the link is
//! congested); frames are dropped when it is. A topic is taken from shared
//! memory only once a receiver of it is on the link, so that a stage
//! waiting for its subscribers waits for the other side too.

pub mod clock;
mod counters;
pub mod envelope;
mod error;
mod offsets;
mod options;
mod receive;
mod send;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use messages::now_ns;
use messages::topics::TopicId;
use zenoh::Wait;

use crate::offsets::Clocks;
use crate::receive::receive;
use crate::send::send;

pub use counters::Counters;
pub use error::BridgeError;
pub use options::{Options, Tls};

/// The default of [`Options::lease_ms`]: zenoh's own.
pub use stages::bridge::DEFAULT_LEASE_MS;

/// Deliveries waiting for the receiving thread at most.
const RECEIVE_QUEUE: usize = 256;

/// How often the sending side looks at `stop`, and the receiving side at
/// whether the sending side has ended.
const TICK: Duration = Duration::from_millis(100);

/// How long a round trip may take before it counts as unanswered.
const ROUND_TRIP_WITHIN: Duration = Duration::from_millis(500);

/// How far past this host's clock (after the offset and its uncertainty) a
/// received stamp may be: a stamp is made before its message is sent.
const STAMP_SLACK_NS: i64 = 20_000_000;

/// Runs the bridge until SIGINT/SIGTERM, or until `stop` is set (looked at
/// every 100 ms).
pub fn run(options: &Options, counters: &Counters, stop: &AtomicBool) -> Result<(), BridgeError> {
    options.check()?;
    let session = zenoh::open(options.zenoh_config()?)
        .wait()
        .map_err(|e| BridgeError::zenoh("opening the zenoh session", e))?;
    let zid = session.zid().to_string();
    tracing::info!(
        zid,
        listen = ?options.listen,
        connect = ?options.connect,
        namespace = options.namespace,
        send = ?options.send.iter().map(|t| t.name()).collect::<Vec<_>>(),
        receive = ?options.receive.iter().map(|t| t.name()).collect::<Vec<_>>(),
        "bridge up"
    );
    let clock_answers = session
        .declare_queryable(options.clock_key(&zid))
        .callback(|query| {
            let arrived = now_ns();
            let mut times = [0u8; 16];
            times[..8].copy_from_slice(&arrived.to_le_bytes());
            times[8..].copy_from_slice(&now_ns().to_le_bytes());
            if let Err(e) = query.reply(query.key_expr().clone(), times.to_vec()).wait() {
                tracing::debug!("answering a round trip: {e}");
            }
        })
        .wait()
        .map_err(|e| {
            BridgeError::zenoh(
                format!("answering round trips on {}", options.clock_key(&zid)),
                e,
            )
        })?;
    // The layouts this side receives in: the sending side checks them
    // before it sends (and this side checks every message's).
    let layout_answers = options
        .receive
        .iter()
        .map(|&topic| {
            let key = options.layout_key(topic, &zid);
            let answer_key = key.clone();
            session
                .declare_queryable(&key)
                .callback(move |query| {
                    // Answered on this bridge's own key: the asker learns whose.
                    let name = topic.layout().type_name.as_bytes().to_vec();
                    if let Err(e) = query.reply(answer_key.as_str(), name).wait() {
                        tracing::debug!("answering a layout question: {e}");
                    }
                })
                .wait()
                .map_err(|e| BridgeError::zenoh(format!("answering layout questions on {key}"), e))
        })
        .collect::<Result<Vec<_>, BridgeError>>()?;
    let (deliveries, queue) = crossbeam_channel::bounded::<(TopicId, Vec<u8>)>(RECEIVE_QUEUE);
    let queue_full = Arc::new(AtomicU64::new(0));
    let mut subscriptions = Vec::new();
    for &topic in &options.receive {
        let deliveries = deliveries.clone();
        let queue_full = queue_full.clone();
        let subscriber = session
            .declare_subscriber(options.key(topic))
            .callback(move |sample| {
                let bytes = sample.payload().to_bytes().into_owned();
                // Small messages wait for room (zenoh then holds the link's
                // reliable stream back); frames are dropped and counted.
                if topic.carries_frames() {
                    if deliveries.try_send((topic, bytes)).is_err() {
                        queue_full.fetch_add(1, Ordering::Relaxed);
                    }
                } else {
                    let _ = deliveries.send((topic, bytes));
                }
            })
            .wait()
            .map_err(|e| BridgeError::zenoh(format!("subscribing to {}", options.key(topic)), e))?;
        subscriptions.push(subscriber);
    }
    drop(deliveries);
    let clocks = Clocks::new(&session, options);
    // `done` ends the receiving and clock sides when the sending side ends;
    // `failed` ends the sending side when the receiving side fails.
    let (done, failed) = (AtomicBool::new(false), AtomicBool::new(false));
    let result = std::thread::scope(|s| {
        let receiving = s.spawn(|| {
            let result = receive(options, queue, counters, &clocks, &[stop, &done]);
            failed.store(result.is_err(), Ordering::Relaxed);
            result
        });
        if !options.receive.is_empty() {
            s.spawn(|| clocks.keep(&[stop, &done, &failed]));
        }
        let sent = send(options, &session, &zid, counters, &[stop, &failed]);
        done.store(true, Ordering::Relaxed);
        let received = receiving
            .join()
            .map_err(|_| BridgeError::Panicked("receiving"))?;
        sent.and(received)
    });
    Counters::add(&counters.queue_full, queue_full.load(Ordering::Relaxed));
    clocks.log("at exit");
    drop(subscriptions);
    drop(layout_answers);
    drop(clock_answers);
    session
        .close()
        .wait()
        .map_err(|e| BridgeError::zenoh("closing the zenoh session", e))?;
    result
}

fn any_set(flags: &[&AtomicBool]) -> bool {
    flags.iter().any(|f| f.load(Ordering::Relaxed))
}
