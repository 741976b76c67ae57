//! Opening services with the settings every process must agree on, and thin
//! publisher/subscriber wrappers that pair each topic with its event service.

use std::ops::ControlFlow;
use std::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

use messages::service::{EVENT_SUFFIX, FRAME_BUFFER, MAX_PORTS, SMALL_BUFFER};
use messages::topics::{FrameTopic, SmallTopic, TopicId, TopicVisitor};
use messages::{FrameHeader, now_ns};

/// A failure of the shared-memory bus, by kind, so callers can tell a
/// transport failure (iceoryx2's error kept as the source) from a mistake
/// of the caller's.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    /// iceoryx2 failed doing `context`.
    #[error("{context}")]
    Transport {
        /// What was being done.
        context: String,
        /// iceoryx2's error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The pipeline prefix cannot name services.
    #[error("prefix `{0}` is empty or has spaces")]
    BadPrefix(String),
    /// A stage opened a port its declaration does not list.
    #[error("{stage} opens a {direction} of `{topic}`, which its declaration does not list")]
    Undeclared {
        /// The stage (its node name).
        stage: String,
        /// `publisher` or `subscriber`.
        direction: &'static str,
        /// The topic's name.
        topic: &'static str,
    },
    /// Waiting for subscribers was interrupted or timed out.
    #[error("{0}")]
    NoSubscribers(String),
    /// A message or frame that does not fit the port it was given to.
    #[error("{0}")]
    WrongMessage(String),
}

/// Wraps an iceoryx2 error as the source of a [`BusError`] saying `context`.
fn err<E: std::error::Error + Send + Sync + 'static>(
    context: impl Into<String>,
) -> impl FnOnce(E) -> BusError {
    let context = context.into();
    move |e| BusError::Transport {
        context,
        source: Box::new(e),
    }
}

/// The ports a stage declares: what it may publish and subscribe to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ports<'a> {
    /// Topics it subscribes to.
    pub subscribes: &'a [TopicId],
    /// Topics it publishes.
    pub publishes: &'a [TopicId],
}

/// One process's connection to a pipeline: an iceoryx2 node and the prefix
/// of the pipeline's service names.
pub struct Bus {
    node: Node<ipc::Service>,
    prefix: String,
    name: String,
    lossless: bool,
    /// The stage's declared ports, if it declared them: any other port is refused.
    declared: Option<(Vec<TopicId>, Vec<TopicId>)>,
}

impl Bus {
    /// Joins the pipeline `prefix` as node `name`.
    pub fn new(prefix: &str, name: &str) -> Result<Self, BusError> {
        if prefix.is_empty() || prefix.contains(char::is_whitespace) {
            return Err(BusError::BadPrefix(prefix.to_string()));
        }
        // iceoryx2 warns that no config file exists; its defaults are what we use.
        set_log_level_from_env_or(LogLevel::Error);
        let removed = remove_dead_nodes();
        if removed > 0 {
            tracing::info!(
                removed,
                "removed the shared memory left by crashed processes"
            );
        }
        let node_name = NodeName::new(name).map_err(err("node name"))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .create::<ipc::Service>()
            .map_err(err("creating the iceoryx2 node"))?;
        Ok(Self {
            node,
            prefix: prefix.to_string(),
            name: name.to_string(),
            lossless: false,
            declared: None,
        })
    }

    /// Restricts this bus to a stage's declared `ports`: opening any other
    /// port is then a [`BusError::Undeclared`], so a stage's binary cannot
    /// drift from the declaration the launcher reads.
    pub fn declared(mut self, ports: Ports<'_>) -> Self {
        self.declared = Some((ports.subscribes.to_vec(), ports.publishes.to_vec()));
        self
    }

    /// Refuses a port the stage did not declare.
    fn check_declared(&self, topic: TopicId, publishes: bool) -> Result<(), BusError> {
        let Some((subscribes, publishes_list)) = &self.declared else {
            return Ok(());
        };
        let list = if publishes {
            publishes_list
        } else {
            subscribes
        };
        if list.contains(&topic) {
            return Ok(());
        }
        Err(BusError::Undeclared {
            stage: self.name.clone(),
            direction: if publishes { "publisher" } else { "subscriber" },
            topic: topic.name(),
        })
    }

    /// Creates services whose full subscriber buffers make publishers wait
    /// instead of overwriting the oldest message, so nothing is lost and a
    /// source runs as fast as its slowest consumer (replay in lockstep).
    ///
    /// Only the creator of a service decides this: every stage that opens
    /// it later inherits it, so create the services before starting the
    /// stages. Opening a service that already overwrites is an error.
    pub fn lossless(mut self) -> Self {
        self.lossless = true;
        self
    }

    /// Sleeps for `period`; `false` if SIGINT or SIGTERM asked the process
    /// to stop (for loops that wait without a [`Wake`]).
    pub fn sleep(&self, period: Duration) -> bool {
        self.node.wait(period).is_ok()
    }

    /// The pipeline's prefix.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    fn name(&self, topic: &str, suffix: &str) -> Result<ServiceName, BusError> {
        let full = messages::service::name(&self.prefix, topic) + suffix;
        ServiceName::new(&full).map_err(err(format!("service name {full}")))
    }

    fn event(&self, topic: &str) -> Result<PortFactoryEvent, BusError> {
        self.node
            .service_builder(&self.name(topic, EVENT_SUFFIX)?)
            .event()
            .max_notifiers(MAX_PORTS)
            .max_listeners(MAX_PORTS)
            .max_nodes(MAX_PORTS * 2)
            .open_or_create()
            .map_err(err(format!("event service of {topic}")))
    }

    fn listener(&self, topic: &str) -> Result<Listener<ipc::Service>, BusError> {
        self.event(topic)?
            .listener_builder()
            .create()
            .map_err(err(format!("listener of {topic}")))
    }

    fn notifier(&self, topic: &str) -> Result<Notifier<ipc::Service>, BusError> {
        self.event(topic)?
            .notifier_builder()
            .create()
            .map_err(err(format!("notifier of {topic}")))
    }

    fn small_service<T: SmallTopic>(&self) -> Result<PortFactoryPubSub<T::Message>, BusError> {
        let mut builder = self
            .node
            .service_builder(&self.name(T::NAME, "")?)
            .publish_subscribe::<T::Message>();
        // Set only when lossless: setting it also demands it of an existing service.
        if self.lossless {
            builder = builder.enable_safe_overflow(false);
        }
        builder
            .subscriber_max_buffer_size(SMALL_BUFFER)
            .history_size(0)
            .max_publishers(MAX_PORTS)
            .max_subscribers(MAX_PORTS)
            .max_nodes(MAX_PORTS * 2)
            .open_or_create()
            .map_err(err(format!("service {}", T::NAME)))
    }

    fn frame_service<T: FrameTopic>(&self) -> Result<PortFactoryFrames, BusError> {
        let mut builder = self
            .node
            .service_builder(&self.name(T::NAME, "")?)
            .publish_subscribe::<[u8]>()
            .user_header::<FrameHeader>();
        if self.lossless {
            builder = builder.enable_safe_overflow(false);
        }
        builder
            .subscriber_max_buffer_size(FRAME_BUFFER)
            .history_size(0)
            .max_publishers(MAX_PORTS)
            .max_subscribers(MAX_PORTS)
            .max_nodes(MAX_PORTS * 2)
            .open_or_create()
            .map_err(err(format!("service {}", T::NAME)))
    }

    /// A publisher of topic `T`'s small fixed-size messages.
    pub fn publisher<T: SmallTopic>(&self) -> Result<Publisher<T>, BusError> {
        self.check_declared(T::ID, true)?;
        let publisher = self
            .small_service::<T>()?
            .publisher_builder()
            .create()
            .map_err(err(format!("publisher of {}", T::NAME)))?;
        Ok(Publisher {
            publisher,
            notifier: self.notifier(T::NAME)?,
        })
    }

    /// A subscriber of topic `T`'s small fixed-size messages.
    pub fn subscriber<T: SmallTopic>(&self) -> Result<Subscriber<T>, BusError> {
        self.check_declared(T::ID, false)?;
        let subscriber = self
            .small_service::<T>()?
            .subscriber_builder()
            .buffer_size(SMALL_BUFFER)
            .create()
            .map_err(err(format!("subscriber of {}", T::NAME)))?;
        Ok(Subscriber {
            subscriber,
            listener: self.listener(T::NAME)?,
        })
    }

    /// A publisher of stereo frames on topic `T` of up to `max_bytes` (both images).
    pub fn frame_publisher<T: FrameTopic>(
        &self,
        max_bytes: usize,
    ) -> Result<FramePublisher, BusError> {
        self.check_declared(T::ID, true)?;
        let publisher = self
            .frame_service::<T>()?
            .publisher_builder()
            .initial_max_slice_len(max_bytes)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .max_loaned_samples(2)
            .create()
            .map_err(err(format!("publisher of {}", T::NAME)))?;
        Ok(FramePublisher {
            publisher,
            notifier: self.notifier(T::NAME)?,
        })
    }

    /// A subscriber of stereo frames on topic `T`.
    pub fn frame_subscriber<T: FrameTopic>(&self) -> Result<FrameSubscriber, BusError> {
        self.check_declared(T::ID, false)?;
        let subscriber = self
            .frame_service::<T>()?
            .subscriber_builder()
            .buffer_size(FRAME_BUFFER)
            .create()
            .map_err(err(format!("subscriber of {}", T::NAME)))?;
        Ok(FrameSubscriber {
            subscriber,
            listener: self.listener(T::NAME)?,
        })
    }

    /// Number of subscribers currently attached to `topic`.
    pub fn subscriber_count(&self, topic: TopicId) -> Result<usize, BusError> {
        struct Count<'a>(&'a Bus);
        impl TopicVisitor for Count<'_> {
            type Output = Result<usize, BusError>;
            fn small<T: SmallTopic>(self) -> Self::Output {
                Ok(self
                    .0
                    .small_service::<T>()?
                    .dynamic_config()
                    .number_of_subscribers())
            }
            fn frames<T: FrameTopic>(self) -> Self::Output {
                Ok(self
                    .0
                    .frame_service::<T>()?
                    .dynamic_config()
                    .number_of_subscribers())
            }
        }
        topic.visit(Count(self))
    }

    /// Waits until `topic` has at least `count` subscribers, polling every
    /// 5 ms; fails after `timeout` or when `stop` says so.
    pub fn wait_for_subscribers(
        &self,
        topic: TopicId,
        count: usize,
        timeout: Duration,
        stop: &dyn Fn() -> bool,
    ) -> Result<(), BusError> {
        let began = std::time::Instant::now();
        loop {
            let now = self.subscriber_count(topic)?;
            if now >= count {
                return Ok(());
            }
            if stop() {
                return Err(BusError::NoSubscribers(format!(
                    "interrupted while waiting for subscribers of `{}`",
                    topic.name()
                )));
            }
            if began.elapsed() > timeout {
                return Err(BusError::NoSubscribers(format!(
                    "topic `{}` has {now} subscribers after {:.0} s, waiting for {count}",
                    topic.name(),
                    timeout.as_secs_f64()
                )));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Whether `topic`'s data and event services exist (someone holds them
    /// open), without creating them.
    pub fn service_exists(&self, topic: TopicId) -> Result<bool, BusError> {
        let exists = |name: &ServiceName, pattern| {
            ipc::Service::does_exist(name, Config::global_config(), pattern)
                .map_err(err(format!("looking up the services of {}", topic.name())))
        };
        Ok(exists(
            &self.name(topic.name(), "")?,
            MessagingPattern::PublishSubscribe,
        )? && exists(
            &self.name(topic.name(), EVENT_SUFFIX)?,
            MessagingPattern::Event,
        )?)
    }

    /// Opens (creating if needed) the services of every topic of the
    /// [`messages::topics`] table and keeps them for as long as the returned
    /// value lives, so that they exist with this bus's settings before any
    /// stage starts, and outlive any stage: when a crashed stage is cleaned
    /// up, only its ports go, never a service another stage is about to
    /// reattach to.
    pub fn open_all(&self) -> Result<OpenServices, BusError> {
        struct Open<'a>(&'a Bus);
        impl TopicVisitor for Open<'_> {
            type Output = Result<Box<dyn std::any::Any>, BusError>;
            fn small<T: SmallTopic>(self) -> Self::Output {
                Ok(Box::new(self.0.small_service::<T>()?))
            }
            fn frames<T: FrameTopic>(self) -> Self::Output {
                Ok(Box::new(self.0.frame_service::<T>()?))
            }
        }
        let mut held = Vec::new();
        for topic in TopicId::ALL {
            held.push(topic.visit(Open(self))?);
            held.push(Box::new(self.event(topic.name())?));
        }
        Ok(OpenServices { _held: held })
    }

    /// A waitset to sleep on the subscribers' events.
    pub fn wake(&self) -> Result<Wake, BusError> {
        Ok(Wake {
            waitset: WaitSetBuilder::new()
                .create::<ipc::Service>()
                .map_err(err("waitset"))?,
        })
    }
}

/// Removes what processes that died without cleaning up (SIGKILL, a crash)
/// left in shared memory, and takes them off every service they were
/// attached to; returns how many there were. Only the current user's nodes
/// can be seen and removed. (iceoryx2 also does this when a node is created;
/// doing it first lets the stage say so.)
///
/// iceoryx2 0.10 cannot finish removing a node that was killed while it was
/// still creating a port: one tag file stays in its directory under
/// `/tmp/iceoryx2/nodes` and every later start fails on it again (logged at
/// debug level).
pub fn remove_dead_nodes() -> usize {
    let mut removed = 0;
    let listed = Node::<ipc::Service>::list(Config::global_config(), |state| {
        let id = *state.node_id();
        if let NodeState::Dead(view) = state {
            match view.try_remove_stale_resources() {
                Ok(()) => removed += 1,
                Err(e) => tracing::debug!(?id, "dead iceoryx2 node not removed: {e:?}"),
            }
        }
        CallbackProgression::Continue
    });
    if let Err(e) = listed {
        tracing::warn!("cannot list the iceoryx2 nodes to remove dead ones: {e:?}");
    }
    removed
}

/// Every topic's services (data and event), held open (see [`Bus::open_all`]).
pub struct OpenServices {
    _held: Vec<Box<dyn std::any::Any>>,
}

type PortFactoryEvent = iceoryx2::service::port_factory::event::PortFactory<ipc::Service>;
type PortFactoryPubSub<T> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>;
type PortFactoryFrames = iceoryx2::service::port_factory::publish_subscribe::PortFactory<
    ipc::Service,
    [u8],
    FrameHeader,
>;

/// Publishes topic `T`'s messages and wakes the subscribers.
pub struct Publisher<T: SmallTopic> {
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, T::Message, ()>,
    notifier: Notifier<ipc::Service>,
}

impl<T: SmallTopic> Publisher<T> {
    /// Sends a message (written straight into shared memory) and notifies.
    pub fn send(&self, message: T::Message) -> Result<(), BusError> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(err(format!("loan on {}", T::NAME)))?;
        sample
            .write_payload(message)
            .send()
            .map_err(err(format!("send on {}", T::NAME)))?;
        self.notifier
            .notify()
            .map_err(err(format!("notify on {}", T::NAME)))?;
        Ok(())
    }
}

/// Receives topic `T`'s messages; its listener wakes a [`Wake`].
pub struct Subscriber<T: SmallTopic> {
    subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, T::Message, ()>,
    listener: Listener<ipc::Service>,
}

impl<T: SmallTopic> Subscriber<T> {
    /// The next message, if any (copied out: these are small).
    pub fn receive(&self) -> Result<Option<T::Message>, BusError> {
        self.listener
            .try_wait(|_| {})
            .map_err(err(format!("listener of {}", T::NAME)))?;
        Ok(self
            .subscriber
            .receive()
            .map_err(err(format!("receive on {}", T::NAME)))?
            .map(|s| *s.payload()))
    }

    /// The event listener, to attach to a [`Wake`].
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }
}

/// Publishes stereo frames rendered or decoded straight into shared memory.
pub struct FramePublisher {
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, [u8], FrameHeader>,
    notifier: Notifier<ipc::Service>,
}

impl FramePublisher {
    /// Loans `2 * header.image_len()` bytes, lets `fill` draw both images in
    /// place (left, right), stamps [`FrameHeader::published_ns`], then sends
    /// and notifies. `fill` must write every byte: the loan is not cleared
    /// and holds an earlier frame. It returns whether it made a frame (a
    /// source at its end does not): only then is the frame sent, and
    /// `publish` says whether it was.
    pub fn publish<E>(
        &self,
        header: FrameHeader,
        fill: impl FnOnce(&mut [u8], &mut [u8]) -> Result<bool, E>,
    ) -> Result<Result<bool, E>, BusError> {
        self.send_frame(header, true, fill)
    }

    /// As [`FramePublisher::publish`], but keeps `header` as given, with its
    /// recorded `published_ns` (replay).
    pub fn publish_as_recorded<E>(
        &self,
        header: FrameHeader,
        fill: impl FnOnce(&mut [u8], &mut [u8]) -> Result<bool, E>,
    ) -> Result<Result<bool, E>, BusError> {
        self.send_frame(header, false, fill)
    }

    #[allow(unsafe_code)]
    fn send_frame<E>(
        &self,
        header: FrameHeader,
        stamp: bool,
        fill: impl FnOnce(&mut [u8], &mut [u8]) -> Result<bool, E>,
    ) -> Result<Result<bool, E>, BusError> {
        let len = header.image_len();
        // Uninitialised as far as the types go: `loan_slice` would zero-fill
        // the 600 KiB of a stereo frame on every loan, which cost more than
        // the whole hop did otherwise (see the IPC benchmark).
        let mut sample = self
            .publisher
            .loan_slice_uninit(2 * len)
            .map_err(err("loan a frame"))?;
        *sample.user_header_mut() = header;
        let payload = sample.payload_mut();
        // SAFETY: the payload lies in a shared-memory segment mapped from
        // /dev/shm. The kernel zero-fills its pages when they are first
        // mapped and earlier frames have written over them since, so every
        // byte is initialised memory; `MaybeUninit` is only the loan's
        // type-level caution. `u8` has no invalid bit patterns.
        let bytes: &mut [u8] =
            unsafe { &mut *(payload as *mut [std::mem::MaybeUninit<u8>] as *mut [u8]) };
        let (left, right) = bytes.split_at_mut(len);
        match fill(left, right) {
            Ok(true) => {}
            // Dropping the loan returns it unsent.
            Ok(false) => return Ok(Ok(false)),
            Err(e) => return Ok(Err(e)),
        }
        if stamp {
            sample.user_header_mut().published_ns = now_ns();
        }
        // SAFETY: every byte is initialised (see above).
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(err("send a frame"))?;
        self.notifier.notify().map_err(err("notify a frame"))?;
        Ok(Ok(true))
    }
}

/// Receives stereo frames without copying them.
pub struct FrameSubscriber {
    subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, [u8], FrameHeader>,
    listener: Listener<ipc::Service>,
}

impl FrameSubscriber {
    /// Calls `f` on the next frame in shared memory, if any.
    pub fn receive_with<R>(
        &self,
        f: impl FnOnce(&FrameHeader, &[u8]) -> R,
    ) -> Result<Option<R>, BusError> {
        self.listener
            .try_wait(|_| {})
            .map_err(err("frame listener"))?;
        match self.subscriber.receive().map_err(err("receive a frame"))? {
            Some(sample) => Ok(Some(f(sample.user_header(), sample.payload()))),
            None => Ok(None),
        }
    }

    /// The event listener, to attach to a [`Wake`].
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }
}

/// Sleeps until a subscriber is notified, a period passes, or a signal asks
/// the process to stop.
pub struct Wake {
    waitset: WaitSet<ipc::Service>,
}

impl Wake {
    /// Runs `on_wake` each time any of `listeners` is notified or `tick`
    /// passes, until it breaks or fails, or SIGINT/SIGTERM arrives (after
    /// which it runs once more, to take what is waiting). Its error stops
    /// the loop and is returned.
    pub fn run<E: From<BusError>>(
        &self,
        listeners: &[&Listener<ipc::Service>],
        tick: Option<Duration>,
        mut on_wake: impl FnMut() -> Result<ControlFlow<()>, E>,
    ) -> Result<(), E> {
        let mut guards = Vec::new();
        for l in listeners {
            guards.push(
                self.waitset
                    .attach_notification(*l)
                    .map_err(err("attach a listener"))?,
            );
        }
        let _interval = match tick {
            Some(period) => Some(
                self.waitset
                    .attach_interval(period)
                    .map_err(err("attach an interval"))?,
            ),
            None => None,
        };
        // Deliver anything that arrived before we attached.
        if on_wake()?.is_break() {
            return Ok(());
        }
        let mut failure = None;
        let result = self
            .waitset
            .wait_and_process(|_| match on_wake() {
                Ok(ControlFlow::Continue(())) => CallbackProgression::Continue,
                Ok(ControlFlow::Break(())) => CallbackProgression::Stop,
                Err(e) => {
                    failure = Some(e);
                    CallbackProgression::Stop
                }
            })
            .map_err(err("waitset"))?;
        if let Some(e) = failure {
            return Err(e);
        }
        // Stopped by a signal: handle what already arrived, so that a stage
        // stopped after its source has finished loses nothing.
        if matches!(
            result,
            WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest
        ) {
            let _ = on_wake()?;
        }
        drop(guards);
        Ok(())
    }
}
