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
pub mod envelope;

use std::cell::Cell;
use std::collections::HashMap;
use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use messages::now_ns;
use messages::topics::TopicId;
use runtime::stats::StageStats;
use runtime::{AnyPublisher, AnySubscriber, Bus, Rejections};
use zenoh::Wait;
use zenoh::qos::{CongestionControl, Priority};

use crate::clock::{Applied, Estimator, Offset, RoundTrip};

/// Where the link goes and what crosses it.
#[derive(Debug, Clone)]
pub struct Options {
    /// Service prefix of the pipeline on this host.
    pub prefix: String,
    /// First part of every zenoh key; both sides must agree on it. A second
    /// robot uses another.
    pub namespace: String,
    /// Topics read here and sent.
    pub send: Vec<TopicId>,
    /// Topics received and published here.
    pub receive: Vec<TopicId>,
    /// Zenoh endpoints to listen on (e.g. `tcp/0.0.0.0:7447`).
    pub listen: Vec<String>,
    /// Zenoh endpoints to connect to (e.g. `tcp/192.168.1.20:7447`).
    pub connect: Vec<String>,
    /// How frames travel (small messages always as they are).
    pub frame_encoding: envelope::Encoding,
    /// How long the link may stay silent before it counts as cut, ms (then
    /// both sides count what they send as lost, and the connecting side
    /// connects again every 1 to 4 s).
    pub lease_ms: u64,
}

/// The default of [`Options::lease_ms`]: zenoh's own.
pub use stages::bridge::DEFAULT_LEASE_MS;

impl Options {
    /// Refuses what cannot work: a topic both sent and received would come
    /// back to its sender and go round the link for ever.
    pub fn check(&self) -> Result<()> {
        if let Some(t) = self.send.iter().find(|t| self.receive.contains(t)) {
            bail!(
                "topic {} is both sent and received; each topic crosses one way",
                t.name()
            );
        }
        if self.send.is_empty() && self.receive.is_empty() {
            bail!("nothing to bridge: give --send and/or --receive");
        }
        if self.listen.is_empty() && self.connect.is_empty() {
            bail!("no link: give --listen and/or --connect");
        }
        if !(100..=600_000).contains(&self.lease_ms) {
            bail!("lease {} ms is not within 100 ms to 10 min", self.lease_ms);
        }
        if self.namespace.is_empty() || self.namespace.contains(['*', '$', '#', '?']) {
            bail!("namespace {:?} is not a plain zenoh key", self.namespace);
        }
        Ok(())
    }

    /// The zenoh key of `topic`.
    pub fn key(&self, topic: TopicId) -> String {
        format!("{}/{}", self.namespace, topic.name())
    }

    /// The zenoh key on which the bridge `zid` answers round trips.
    pub fn clock_key(&self, zid: &str) -> String {
        format!("{}/_clock/{zid}", self.namespace)
    }

    /// The zenoh key on which the bridge `zid` (or `*`: every bridge) tells
    /// the layout it receives `topic` in.
    pub fn layout_key(&self, topic: TopicId, zid: &str) -> String {
        format!("{}/_layout/{}/{zid}", self.namespace, topic.name())
    }

    /// The zenoh configuration: a peer at the given endpoints, without
    /// multicast scouting (the endpoints are explicit, and a robot's network
    /// should not join whatever zenoh peers it hears).
    pub fn zenoh_config(&self) -> Result<zenoh::Config> {
        let mut config = zenoh::Config::default();
        let json = |v: &[String]| format!("{v:?}");
        let mut set = |key: &str, value: String| {
            config
                .insert_json5(key, &value)
                .map_err(|e| anyhow::anyhow!("zenoh config {key} = {value}: {e}"))
        };
        set("mode", "\"peer\"".into())?;
        set("scouting/multicast/enabled", "false".into())?;
        set("listen/endpoints", json(&self.listen))?;
        set("connect/endpoints", json(&self.connect))?;
        set("transport/link/tx/lease", self.lease_ms.to_string())?;
        // Frames travel on their own priority queue, below the small
        // messages, so joint states never wait behind a frame's fragments.
        // That queue holds a whole frame (16 batches of 64 KiB), and a frame
        // is dropped only when the link has had no room for it for a while:
        // zenoh's default (1 ms a batch) dropped frames on a busy two-core
        // machine whenever its sending thread was not scheduled for a moment.
        set(
            "transport/link/tx/queue/size/data_low",
            FRAME_QUEUE_BATCHES.to_string(),
        )?;
        set(
            "transport/link/tx/queue/congestion_control/drop/wait_before_drop",
            FRAME_WAIT_US.to_string(),
        )?;
        set(
            "transport/link/tx/queue/congestion_control/drop/max_wait_before_drop_fragments",
            FRAME_WAIT_MAX_US.to_string(),
        )?;
        Ok(config)
    }
}

/// Batches of 64 KiB the link queues for frames: zenoh's most.
const FRAME_QUEUE_BATCHES: usize = 16;

/// How long a frame waits for room on the link before it is dropped, per
/// batch, us: longer than a busy machine leaves a thread unscheduled.
const FRAME_WAIT_US: u64 = 20_000;

/// The most a frame of many batches waits in all, us: about two frame
/// periods at 30 fps (a frame later than that is stale).
const FRAME_WAIT_MAX_US: u64 = 66_000;

/// What a bridge did, per topic (by [`TopicId::index`]), and its latencies.
pub struct Counters {
    /// Messages put on the link.
    pub sent: [AtomicU64; TopicId::COUNT],
    /// Of those, messages put while no receiver was on the link (lost).
    pub unheard: [AtomicU64; TopicId::COUNT],
    /// Messages taken from shared memory but dropped because the queue to
    /// the link was full (a link stalled for long).
    pub dropped: [AtomicU64; TopicId::COUNT],
    /// Messages received and published here.
    pub received: [AtomicU64; TopicId::COUNT],
    /// Messages the sender numbered but that never came (gaps in its
    /// sequence numbers: a cut link, a full link or queue).
    pub lost: [AtomicU64; TopicId::COUNT],
    /// Messages from the link refused (they did not open, came out of
    /// order, or their stamps cannot be).
    pub refused: AtomicU64,
    /// Frames dropped because the receiving queue was full.
    pub queue_full: AtomicU64,
    /// Latencies: `link` (sent there to received here, on this clock) and
    /// `clock_uncertainty` (of the offset each received message was moved by).
    pub stats: Mutex<StageStats>,
}

impl Default for Counters {
    fn default() -> Self {
        Self {
            sent: Default::default(),
            unheard: Default::default(),
            dropped: Default::default(),
            received: Default::default(),
            lost: Default::default(),
            refused: AtomicU64::new(0),
            queue_full: AtomicU64::new(0),
            stats: Mutex::new(StageStats::new("bridge")),
        }
    }
}

impl Counters {
    fn add(slot: &AtomicU64, n: u64) {
        slot.fetch_add(n, Ordering::Relaxed);
    }

    fn get(slots: &[AtomicU64; TopicId::COUNT], topic: TopicId) -> u64 {
        slots[topic.index()].load(Ordering::Relaxed)
    }

    /// The stage stats with every counter of `options`' topics added.
    pub fn into_stats(self, options: &Options) -> StageStats {
        let mut stats = self.stats.into_inner().unwrap_or_else(|p| p.into_inner());
        for t in TopicId::ALL {
            let name = t.name();
            if options.send.contains(&t) {
                stats.count(&format!("sent_{name}"), Self::get(&self.sent, t));
                stats.count(&format!("unheard_{name}"), Self::get(&self.unheard, t));
                stats.count(&format!("dropped_{name}"), Self::get(&self.dropped, t));
            }
            if options.receive.contains(&t) {
                stats.count(&format!("received_{name}"), Self::get(&self.received, t));
                stats.count(&format!("lost_{name}"), Self::get(&self.lost, t));
            }
        }
        stats.count("refused", self.refused.load(Ordering::Relaxed));
        stats.count("queue_full", self.queue_full.load(Ordering::Relaxed));
        stats
    }
}

/// Deliveries waiting for the receiving thread at most.
const RECEIVE_QUEUE: usize = 256;

/// How often the sending side looks at `stop`, and the receiving side at
/// whether the sending side has ended.
const TICK: Duration = Duration::from_millis(100);

/// How often the clock thread makes a round trip to each sender: 16 of them
/// (the estimator's window) span 4 s.
const CLOCK_EVERY: Duration = Duration::from_millis(250);

/// How long a round trip may take before it counts as unanswered.
const ROUND_TRIP_WITHIN: Duration = Duration::from_millis(500);

/// How far past this host's clock (after the offset and its uncertainty) a
/// received stamp may be: a stamp is made before its message is sent.
const STAMP_SLACK_NS: i64 = 20_000_000;

/// Runs the bridge until SIGINT/SIGTERM, or until `stop` is set (looked at
/// every 100 ms).
pub fn run(options: &Options, counters: &Counters, stop: &AtomicBool) -> Result<()> {
    options.check()?;
    let session = zenoh::open(options.zenoh_config()?)
        .wait()
        .map_err(|e| anyhow::anyhow!("opening the zenoh session: {e}"))?;
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
            anyhow::anyhow!("answering round trips on {}: {e}", options.clock_key(&zid))
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
                .map_err(|e| anyhow::anyhow!("answering layout questions on {key}: {e}"))
        })
        .collect::<Result<Vec<_>>>()?;
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
            .map_err(|e| anyhow::anyhow!("subscribing to {}: {e}", options.key(topic)))?;
        subscriptions.push(subscriber);
    }
    drop(deliveries);
    let clocks = Clocks {
        session: &session,
        options,
        senders: Mutex::new(HashMap::new()),
        unanswered: Mutex::new(HashMap::new()),
    };
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
            .map_err(|_| anyhow::anyhow!("the receiving thread panicked"))?;
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
        .map_err(|e| anyhow::anyhow!("closing the zenoh session: {e}"))?;
    result
}

fn any_set(flags: &[&AtomicBool]) -> bool {
    flags.iter().any(|f| f.load(Ordering::Relaxed))
}

/// The offsets to the clocks of the bridges that send here.
struct Clocks<'a> {
    session: &'a zenoh::Session,
    options: &'a Options,
    /// By sender's zenoh id.
    senders: Mutex<HashMap<String, SenderClock>>,
    /// When (this clock, ns) a sender without an offset last failed to
    /// answer: its messages are refused at once for a while, so that a
    /// sender that never answers (or a stream of made-up ids) cannot hold
    /// the receiving side in round trips.
    unanswered: Mutex<HashMap<String, i64>>,
}

/// What is known of one sender's clock: the estimate, and the offsets
/// applied to its stamps.
#[derive(Default)]
struct SenderClock {
    estimator: Estimator,
    applied: Applied,
}

/// How long a sender without an offset that did not answer is not asked
/// again.
const ASK_AGAIN_AFTER_NS: i64 = 5_000_000_000;

/// A sender that answered no round trip for this long is forgotten (it has
/// gone; if it comes back, it is asked again).
const FORGET_AFTER_NS: i64 = 10_000_000_000;

impl Clocks<'_> {
    /// One round trip to `zid`, if it answers in time.
    fn round_trip(&self, zid: &str) -> Option<RoundTrip> {
        let t1 = now_ns();
        let replies = self
            .session
            .get(self.options.clock_key(zid))
            .timeout(ROUND_TRIP_WITHIN)
            .wait()
            .ok()?;
        let reply = replies.recv().ok()?;
        let t4 = now_ns();
        let payload = reply.result().ok()?.payload().to_bytes();
        let times: &[u8; 16] = payload.as_ref().try_into().ok()?;
        let time = |k: usize| i64::from_le_bytes(times[k..k + 8].try_into().expect("8 bytes"));
        Some(RoundTrip {
            t1,
            t2: time(0),
            t3: time(8),
            t4,
        })
    }

    fn add(&self, zid: &str, trip: RoundTrip) {
        let mut senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
        senders
            .entry(zid.to_string())
            .or_default()
            .estimator
            .add(trip);
    }

    fn estimate(&self, zid: &str) -> Option<Offset> {
        let senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
        senders.get(zid)?.estimator.estimate(now_ns())
    }

    /// The offset that moves a stamp `stamp_ns` of `zid` onto this clock
    /// (see [`Applied`]), and the bound on its error now; a sender not
    /// heard from before is asked a few round trips first.
    fn offset(&self, zid: &str, stamp_ns: i64) -> Option<(Offset, i64)> {
        let current = self.current(zid)?;
        let mut senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
        let sender = senders.get_mut(zid)?;
        sender.applied.adopt(current, now_ns(), STAMP_SLACK_NS);
        let applied = sender.applied.at(stamp_ns)?;
        let bound = current
            .uncertainty_ns
            .saturating_add(applied.ahead_ns.abs_diff(current.ahead_ns) as i64);
        Some((applied, bound))
    }

    /// The current estimate of the offset to the clock of `zid`; a sender
    /// not heard from before is asked a few round trips first.
    fn current(&self, zid: &str) -> Option<Offset> {
        if let Some(o) = self.estimate(zid) {
            return Some(o);
        }
        let asked_at = {
            let unanswered = self.unanswered.lock().unwrap_or_else(|p| p.into_inner());
            unanswered.get(zid).copied()
        };
        if asked_at.is_some_and(|at| now_ns() - at < ASK_AGAIN_AFTER_NS) {
            return None;
        }
        for _ in 0..4 {
            if let Some(trip) = self.round_trip(zid) {
                self.add(zid, trip);
            }
        }
        let Some(o) = self.estimate(zid) else {
            let mut unanswered = self.unanswered.lock().unwrap_or_else(|p| p.into_inner());
            let now = now_ns();
            unanswered.retain(|_, at| now - *at < ASK_AGAIN_AFTER_NS);
            unanswered.insert(zid.to_string(), now);
            return None;
        };
        tracing::info!(
            sender = zid,
            ahead_s = o.ahead_ns as f64 * 1e-9,
            uncertainty_us = o.uncertainty_ns as f64 * 1e-3,
            "clock of a new sender"
        );
        Some(o)
    }

    /// Keeps every known sender's offset fresh until one of `stops`.
    fn keep(&self, stops: &[&AtomicBool]) {
        let mut logged = Instant::now();
        while !any_set(stops) {
            let zids: Vec<String> = {
                let senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
                senders.keys().cloned().collect()
            };
            for zid in zids {
                if let Some(trip) = self.round_trip(&zid) {
                    self.add(&zid, trip);
                }
            }
            let mut senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
            senders.retain(|zid, e| {
                let answered = e
                    .estimator
                    .last_trip_ns()
                    .is_some_and(|at| now_ns() - at < FORGET_AFTER_NS);
                if !answered {
                    tracing::info!(
                        sender = zid,
                        "a sender stopped answering round trips: forgotten"
                    );
                }
                answered
            });
            drop(senders);
            if logged.elapsed() > Duration::from_secs(30) {
                self.log("now");
                logged = Instant::now();
            }
            std::thread::sleep(CLOCK_EVERY);
        }
    }

    fn log(&self, when: &str) {
        let senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
        for (zid, e) in senders.iter().map(|(z, s)| (z, &s.estimator)) {
            if let Some(o) = e.estimate(now_ns()) {
                tracing::info!(
                    sender = zid,
                    ahead_s = o.ahead_ns as f64 * 1e-9,
                    uncertainty_us = o.uncertainty_ns as f64 * 1e-3,
                    refused_round_trips = e.refused,
                    "clock offset {when}"
                );
            }
        }
    }
}

/// The sending side: until a signal or one of `stops`.
fn send(
    options: &Options,
    session: &zenoh::Session,
    zid: &str,
    counters: &Counters,
    stops: &[&AtomicBool],
) -> Result<()> {
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
            .map_err(|e| anyhow::anyhow!("publishing {}: {e}", options.key(topic)))?;
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
        .collect::<Result<Vec<_>>>()?;
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
        let taken = bus.wake()?.run(&listeners, Some(TICK), || -> Result<_> {
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
            .map_err(|_| anyhow::anyhow!("the putting thread panicked"))?;
        taken.and(put)
    })
}

/// Asks every receiving bridge on the link which layout it takes `topic`
/// in; one that differs from this side's is an error naming both (the two
/// hosts run builds that do not agree: nothing of the topic would open).
fn check_layouts(options: &Options, session: &zenoh::Session, topic: TopicId) -> Result<()> {
    let ours = topic.layout().type_name;
    let replies = session
        .get(options.layout_key(topic, "*"))
        .timeout(ROUND_TRIP_WITHIN)
        .wait()
        .map_err(|e| anyhow::anyhow!("asking the receivers' layouts of {}: {e}", topic.name()))?;
    while let Ok(reply) = replies.recv() {
        let Ok(sample) = reply.result() else { continue };
        let theirs = String::from_utf8_lossy(&sample.payload().to_bytes()).into_owned();
        if theirs != ours {
            let receiver = sample.key_expr().as_str().rsplit('/').next().unwrap_or("?");
            bail!(
                "layout mismatch on {}: this side's is {ours}, the receiver {receiver}'s is {theirs}",
                topic.name()
            );
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
) -> Result<()> {
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
            .map_err(|e| anyhow::anyhow!("sending on {}: {e}", out.topic.name()))?;
        Counters::add(&counters.sent[out.topic.index()], 1);
    }
    Ok(())
}

/// The receiving side: until one of `stops`.
fn receive(
    options: &Options,
    queue: crossbeam_channel::Receiver<(TopicId, Vec<u8>)>,
    counters: &Counters,
    clocks: &Clocks<'_>,
    stops: &[&AtomicBool],
) -> Result<()> {
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
                rejections.reject("message from the link", n, &why);
                continue;
            }
        };
        let publisher = match &mut publishers[topic.index()] {
            Some(p) => p,
            slot => slot.insert(
                AnyPublisher::new(&bus, topic, bytes.len())
                    .with_context(|| format!("publishing {} here", topic.name()))?,
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
) -> Result<messages::topics::Message<'a>, String> {
    let opened = envelope::open(topic, bytes, scratch)?;
    let from = opened.from;
    let seen = last.entry((from.sender.to_string(), topic)).or_insert(0);
    if from.seq <= *seen {
        return Err(format!(
            "{} message {} from {} after its message {} (repeated or out of order)",
            topic.name(),
            from.seq,
            from.sender,
            seen
        ));
    }
    // The first message heard from a sender sets where its count starts.
    if *seen > 0 {
        Counters::add(&counters.lost[topic.index()], from.seq - *seen - 1);
    }
    *seen = from.seq;
    let mut message = opened.message;
    let (offset, uncertainty_ns) =
        clocks
            .offset(from.sender, message.stamp_ns())
            .ok_or_else(|| {
                format!(
                    "no clock offset to {}: it does not answer round trips",
                    from.sender
                )
            })?;
    message.shift_clock(offset.ahead_ns.saturating_neg());
    let now = now_ns();
    let ahead = message.stamp_ns().saturating_sub(now);
    if ahead > uncertainty_ns.saturating_add(STAMP_SLACK_NS) {
        return Err(format!(
            "{} stamp {:.3} s ahead of this host's clock (offset uncertainty {:.0} us)",
            topic.name(),
            ahead as f64 * 1e-9,
            uncertainty_ns as f64 * 1e-3
        ));
    }
    let sent_here = from.sent_ns.saturating_sub(offset.ahead_ns);
    let mut stats = counters.stats.lock().unwrap_or_else(|p| p.into_inner());
    stats.record("link", now.saturating_sub(sent_here));
    stats.record("clock_uncertainty", uncertainty_ns);
    Ok(message)
}
