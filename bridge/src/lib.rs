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
//! Two threads: the sending one sleeps on the subscribers' events and puts
//! each message on the link; the receiving one takes zenoh's deliveries
//! from a bounded queue and publishes them. Small messages are sent
//! reliably (zenoh blocks rather than drops them when the link is
//! congested); frames are dropped when it is.

pub mod envelope;

use std::ops::ControlFlow;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use messages::topics::{FrameTopic, SmallTopic, TopicId, TopicVisitor};
use messages::{
    AnyPublisher, Bus, BusError, FrameHeader, FrameSubscriber, Rejections, Subscriber, now_ns,
};
use zenoh::Wait;
use zenoh::qos::CongestionControl;

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
}

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
        if self.namespace.is_empty() || self.namespace.contains(['*', '$', '#', '?']) {
            bail!("namespace {:?} is not a plain zenoh key", self.namespace);
        }
        Ok(())
    }

    /// The zenoh key of `topic`.
    pub fn key(&self, topic: TopicId) -> String {
        format!("{}/{}", self.namespace, topic.name())
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
        Ok(config)
    }
}

/// What a bridge did, per topic (by [`TopicId::index`]).
#[derive(Debug, Default)]
pub struct Counters {
    /// Messages put on the link.
    pub sent: [AtomicU64; TopicId::COUNT],
    /// Messages received and published here.
    pub received: [AtomicU64; TopicId::COUNT],
    /// Messages from the link refused (they did not open).
    pub refused: AtomicU64,
    /// Frames dropped because the receiving queue was full.
    pub queue_full: AtomicU64,
}

impl Counters {
    fn add(slot: &AtomicU64) {
        slot.fetch_add(1, Ordering::Relaxed);
    }

    /// Messages sent on `topic`.
    pub fn sent(&self, topic: TopicId) -> u64 {
        self.sent[topic.index()].load(Ordering::Relaxed)
    }

    /// Messages received on `topic`.
    pub fn received(&self, topic: TopicId) -> u64 {
        self.received[topic.index()].load(Ordering::Relaxed)
    }
}

/// Deliveries waiting for the receiving thread at most.
const RECEIVE_QUEUE: usize = 256;

/// Runs the bridge until SIGINT/SIGTERM, or until `stop` is set (looked at
/// every 100 ms).
pub fn run(options: &Options, counters: &Counters, stop: &AtomicBool) -> Result<()> {
    options.check()?;
    let session = zenoh::open(options.zenoh_config()?)
        .wait()
        .map_err(|e| anyhow::anyhow!("opening the zenoh session: {e}"))?;
    tracing::info!(
        zid = %session.zid(),
        listen = ?options.listen,
        connect = ?options.connect,
        namespace = options.namespace,
        send = ?options.send.iter().map(|t| t.name()).collect::<Vec<_>>(),
        receive = ?options.receive.iter().map(|t| t.name()).collect::<Vec<_>>(),
        "bridge up"
    );
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
    // `done` ends the receiving side when the sending side ends; `failed`
    // ends the sending side when the receiving side fails.
    let (done, failed) = (AtomicBool::new(false), AtomicBool::new(false));
    let result = std::thread::scope(|s| {
        let receiving = s.spawn(|| {
            let result = receive(options, queue, counters, stop, &done);
            failed.store(result.is_err(), Ordering::Relaxed);
            result
        });
        let sent = send(options, &session, counters, &[stop, &failed]);
        done.store(true, Ordering::Relaxed);
        let received = receiving
            .join()
            .map_err(|_| anyhow::anyhow!("the receiving thread panicked"))?;
        sent.and(received)
    });
    counters
        .queue_full
        .store(queue_full.load(Ordering::Relaxed), Ordering::Relaxed);
    drop(subscriptions);
    session
        .close()
        .wait()
        .map_err(|e| anyhow::anyhow!("closing the zenoh session: {e}"))?;
    result
}

/// A subscription to one topic that sends what it takes.
trait Tap {
    fn listener(&self) -> &iceoryx2::port::listener::Listener<iceoryx2::prelude::ipc::Service>;
    /// Calls `send` with each waiting message's bytes; returns how many.
    fn drain(&self, send: &mut dyn FnMut(&[u8]) -> Result<()>) -> Result<usize>;
}

struct SmallTap<T: SmallTopic>(Subscriber<T>);

impl<T: SmallTopic> Tap for SmallTap<T> {
    fn listener(&self) -> &iceoryx2::port::listener::Listener<iceoryx2::prelude::ipc::Service> {
        self.0.listener()
    }
    fn drain(&self, send: &mut dyn FnMut(&[u8]) -> Result<()>) -> Result<usize> {
        let mut n = 0;
        while let Some(m) = self.0.receive()? {
            send(bytemuck::bytes_of(&m))?;
            n += 1;
        }
        Ok(n)
    }
}

struct FrameTap(FrameSubscriber);

impl Tap for FrameTap {
    fn listener(&self) -> &iceoryx2::port::listener::Listener<iceoryx2::prelude::ipc::Service> {
        self.0.listener()
    }
    fn drain(&self, send: &mut dyn FnMut(&[u8]) -> Result<()>) -> Result<usize> {
        let mut n = 0;
        // The one copy out of shared memory a network hop needs.
        while let Some(bytes) = self.0.receive_with(|header, payload| {
            let mut bytes = Vec::with_capacity(size_of::<FrameHeader>() + payload.len());
            bytes.extend_from_slice(bytemuck::bytes_of(header));
            bytes.extend_from_slice(payload);
            bytes
        })? {
            send(&bytes)?;
            n += 1;
        }
        Ok(n)
    }
}

struct Subscribe<'a>(&'a Bus);

impl TopicVisitor for Subscribe<'_> {
    type Output = Result<Box<dyn Tap>, BusError>;
    fn small<T: SmallTopic>(self) -> Self::Output {
        Ok(Box::new(SmallTap(self.0.subscriber::<T>()?)))
    }
    fn frames<T: FrameTopic>(self) -> Self::Output {
        Ok(Box::new(FrameTap(self.0.frame_subscriber::<T>()?)))
    }
}

/// The sending side: until a signal or one of `stops`.
fn send(
    options: &Options,
    session: &zenoh::Session,
    counters: &Counters,
    stops: &[&AtomicBool],
) -> Result<()> {
    let bus = Bus::new(&options.prefix, "bridge_send")?;
    let mut taps = Vec::new();
    for &topic in &options.send {
        let tap = topic.visit(Subscribe(&bus))?;
        let congestion = if topic.carries_frames() {
            CongestionControl::Drop
        } else {
            CongestionControl::Block
        };
        let publisher = session
            .declare_publisher(options.key(topic))
            .congestion_control(congestion)
            .wait()
            .map_err(|e| anyhow::anyhow!("publishing {}: {e}", options.key(topic)))?;
        taps.push((topic, tap, publisher));
    }
    let listeners: Vec<_> = taps.iter().map(|(_, tap, _)| tap.listener()).collect();
    bus.wake()?.run(&listeners, Some(TICK), || -> Result<_> {
        for (topic, tap, publisher) in &taps {
            tap.drain(&mut |bytes| {
                publisher
                    .put(envelope::seal(*topic, now_ns(), bytes))
                    .wait()
                    .map_err(|e| anyhow::anyhow!("sending on {}: {e}", topic.name()))?;
                Counters::add(&counters.sent[topic.index()]);
                Ok(())
            })?;
        }
        Ok(if stops.iter().any(|s| s.load(Ordering::Relaxed)) {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        })
    })
}

/// How often the sending side looks at `stop`, and the receiving side at
/// whether the sending side has ended.
const TICK: Duration = Duration::from_millis(100);

/// The receiving side: until the sending side ends (`done`).
fn receive(
    options: &Options,
    queue: crossbeam_channel::Receiver<(TopicId, Vec<u8>)>,
    counters: &Counters,
    stop: &AtomicBool,
    done: &AtomicBool,
) -> Result<()> {
    let bus = Bus::new(&options.prefix, "bridge_receive")?;
    // Publishers made as their topics' first messages come (a frame
    // publisher is sized by its first frame).
    let mut publishers: Vec<Option<AnyPublisher>> = (0..TopicId::COUNT).map(|_| None).collect();
    let mut rejections = Rejections::default();
    let mut seq = 0u64;
    while !(done.load(Ordering::Relaxed) || stop.load(Ordering::Relaxed)) {
        let (topic, bytes) = match queue.recv_timeout(TICK) {
            Ok(delivery) => delivery,
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => continue,
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
        };
        seq += 1;
        let opened = match envelope::open(topic, &bytes) {
            Ok(opened) => opened,
            Err(why) => {
                Counters::add(&counters.refused);
                rejections.reject("message from the link", seq, &why);
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
        publisher.publish(&opened.message)?;
        Counters::add(&counters.received[topic.index()]);
    }
    Ok(())
}
