//! Opening services with the settings every process must agree on, and thin
//! publisher/subscriber wrappers that pair each topic with its event service.

use std::fmt::Debug;
use std::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

use crate::{FrameHeader, now_ns};

/// Buffer of each subscriber of small messages: deep enough that nothing is
/// lost while a stage is busy for seconds (a calibration, a slow start).
const SMALL_BUFFER: usize = 1024;
/// Buffer of each frame subscriber: old frames are overwritten, newest kept.
const FRAME_BUFFER: usize = 4;
const MAX_PORTS: usize = 16;

/// A failure of the shared-memory transport.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{context}: {message}")]
pub struct BusError {
    context: String,
    message: String,
}

fn err(context: impl Into<String>) -> impl FnOnce(&dyn Debug) -> BusError {
    let context = context.into();
    move |e| BusError {
        context,
        message: format!("{e:?}"),
    }
}

/// One process's connection to a pipeline: an iceoryx2 node and the prefix
/// of the pipeline's service names.
pub struct Bus {
    node: Node<ipc::Service>,
    prefix: String,
    lossless: bool,
}

impl Bus {
    /// Joins the pipeline `prefix` as node `name`.
    pub fn new(prefix: &str, name: &str) -> Result<Self, BusError> {
        if prefix.is_empty() || prefix.contains(char::is_whitespace) {
            return Err(BusError {
                context: "prefix".into(),
                message: format!("`{prefix}` is empty or has spaces"),
            });
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
        let node_name = NodeName::new(name).map_err(|e| err("node name")(&e))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .create::<ipc::Service>()
            .map_err(|e| err("creating the iceoryx2 node")(&e))?;
        Ok(Self {
            node,
            prefix: prefix.to_string(),
            lossless: false,
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

    /// The pipeline's prefix.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    fn name(&self, topic: &str, suffix: &str) -> Result<ServiceName, BusError> {
        let full = format!("mirror/{}/{topic}{suffix}", self.prefix);
        ServiceName::new(&full).map_err(|e| err(format!("service name {full}"))(&e))
    }

    fn event(&self, topic: &str) -> Result<PortFactoryEvent, BusError> {
        self.node
            .service_builder(&self.name(topic, "/event")?)
            .event()
            .max_notifiers(MAX_PORTS)
            .max_listeners(MAX_PORTS)
            .max_nodes(MAX_PORTS * 2)
            .open_or_create()
            .map_err(|e| err(format!("event service of {topic}"))(&e))
    }

    fn listener(&self, topic: &str) -> Result<Listener<ipc::Service>, BusError> {
        self.event(topic)?
            .listener_builder()
            .create()
            .map_err(|e| err(format!("listener of {topic}"))(&e))
    }

    fn notifier(&self, topic: &str) -> Result<Notifier<ipc::Service>, BusError> {
        self.event(topic)?
            .notifier_builder()
            .create()
            .map_err(|e| err(format!("notifier of {topic}"))(&e))
    }

    fn small_service<T: ZeroCopySend + Debug + 'static>(
        &self,
        topic: &str,
    ) -> Result<PortFactoryPubSub<T>, BusError> {
        let mut builder = self
            .node
            .service_builder(&self.name(topic, "")?)
            .publish_subscribe::<T>();
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
            .map_err(|e| err(format!("service {topic}"))(&e))
    }

    fn frame_service(&self, topic: &str) -> Result<PortFactoryFrames, BusError> {
        let mut builder = self
            .node
            .service_builder(&self.name(topic, "")?)
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
            .map_err(|e| err(format!("service {topic}"))(&e))
    }

    /// A publisher of small fixed-size messages on `topic`.
    pub fn publisher<T: ZeroCopySend + Debug + Copy + 'static>(
        &self,
        topic: &str,
    ) -> Result<Publisher<T>, BusError> {
        let service = self.small_service::<T>(topic)?;
        let publisher = service
            .publisher_builder()
            .create()
            .map_err(|e| err(format!("publisher of {topic}"))(&e))?;
        let notifier = self.notifier(topic)?;
        Ok(Publisher {
            publisher,
            notifier,
            topic: topic.into(),
        })
    }

    /// A subscriber of small fixed-size messages on `topic`.
    pub fn subscriber<T: ZeroCopySend + Debug + Copy + 'static>(
        &self,
        topic: &str,
    ) -> Result<Subscriber<T>, BusError> {
        let service = self.small_service::<T>(topic)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(SMALL_BUFFER)
            .create()
            .map_err(|e| err(format!("subscriber of {topic}"))(&e))?;
        let listener = self.listener(topic)?;
        Ok(Subscriber {
            subscriber,
            listener,
            topic: topic.into(),
        })
    }

    /// A publisher of stereo frames of up to `max_bytes` (both images).
    pub fn frame_publisher(
        &self,
        topic: &str,
        max_bytes: usize,
    ) -> Result<FramePublisher, BusError> {
        let service = self.frame_service(topic)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(max_bytes)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .max_loaned_samples(2)
            .create()
            .map_err(|e| err(format!("publisher of {topic}"))(&e))?;
        let notifier = self.notifier(topic)?;
        Ok(FramePublisher {
            publisher,
            notifier,
        })
    }

    /// A subscriber of stereo frames.
    pub fn frame_subscriber(&self, topic: &str) -> Result<FrameSubscriber, BusError> {
        let service = self.frame_service(topic)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(FRAME_BUFFER)
            .create()
            .map_err(|e| err(format!("subscriber of {topic}"))(&e))?;
        let listener = self.listener(topic)?;
        Ok(FrameSubscriber {
            subscriber,
            listener,
        })
    }

    /// Number of subscribers currently attached to `topic` (small messages).
    pub fn subscriber_count<T: ZeroCopySend + Debug + Copy + 'static>(
        &self,
        topic: &str,
    ) -> Result<usize, BusError> {
        Ok(self
            .small_service::<T>(topic)?
            .dynamic_config()
            .number_of_subscribers())
    }

    /// Number of subscribers currently attached to the frames `topic`.
    pub fn frame_subscriber_count(&self, topic: &str) -> Result<usize, BusError> {
        Ok(self
            .frame_service(topic)?
            .dynamic_config()
            .number_of_subscribers())
    }

    /// Opens (creating if needed) the services of every topic and keeps them
    /// for as long as the returned value lives, so that they exist with this
    /// bus's settings before any stage starts, and outlive any stage: when a
    /// crashed stage is cleaned up, only its ports go, never a service
    /// another stage is about to reattach to.
    pub fn open_all(&self) -> Result<OpenServices, BusError> {
        use crate::{
            CalibrationMsg, JointState, LocatedObject, MirrorSample, Prediction, StereoDetections,
            topics,
        };
        let mut events = Vec::new();
        for topic in std::iter::once(topics::FRAMES).chain(topics::ALL_SMALL) {
            events.push(self.event(topic)?);
        }
        Ok(OpenServices {
            _events: events,
            _frames: self.frame_service(topics::FRAMES)?,
            _small: (
                self.small_service::<StereoDetections>(topics::DETECTIONS)?,
                self.small_service::<JointState>(topics::JOINT_STATE)?,
                self.small_service::<MirrorSample>(topics::SAMPLES)?,
                self.small_service::<CalibrationMsg>(topics::CALIBRATION)?,
                self.small_service::<Prediction>(topics::PREDICTIONS)?,
                self.small_service::<LocatedObject>(topics::LOCATED)?,
            ),
        })
    }

    /// A waitset to sleep on the subscribers' events.
    pub fn wake(&self) -> Result<Wake, BusError> {
        Ok(Wake {
            waitset: WaitSetBuilder::new()
                .create::<ipc::Service>()
                .map_err(|e| err("waitset")(&e))?,
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
    _events: Vec<PortFactoryEvent>,
    _frames: PortFactoryFrames,
    #[allow(clippy::type_complexity)]
    _small: (
        PortFactoryPubSub<crate::StereoDetections>,
        PortFactoryPubSub<crate::JointState>,
        PortFactoryPubSub<crate::MirrorSample>,
        PortFactoryPubSub<crate::CalibrationMsg>,
        PortFactoryPubSub<crate::Prediction>,
        PortFactoryPubSub<crate::LocatedObject>,
    ),
}

type PortFactoryEvent = iceoryx2::service::port_factory::event::PortFactory<ipc::Service>;
type PortFactoryPubSub<T> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>;
type PortFactoryFrames = iceoryx2::service::port_factory::publish_subscribe::PortFactory<
    ipc::Service,
    [u8],
    FrameHeader,
>;

/// Publishes small messages and wakes the subscribers.
pub struct Publisher<T: ZeroCopySend + Debug + Copy + 'static> {
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, T, ()>,
    notifier: Notifier<ipc::Service>,
    topic: String,
}

impl<T: ZeroCopySend + Debug + Copy + 'static> Publisher<T> {
    /// Sends a message (written straight into shared memory) and notifies.
    pub fn send(&self, message: T) -> Result<(), BusError> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| err(format!("loan on {}", self.topic))(&e))?;
        sample
            .write_payload(message)
            .send()
            .map_err(|e| err(format!("send on {}", self.topic))(&e))?;
        self.notifier
            .notify()
            .map_err(|e| err(format!("notify on {}", self.topic))(&e))?;
        Ok(())
    }
}

/// Receives small messages; its listener wakes a [`Wake`].
pub struct Subscriber<T: ZeroCopySend + Debug + Copy + 'static> {
    subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, T, ()>,
    listener: Listener<ipc::Service>,
    topic: String,
}

impl<T: ZeroCopySend + Debug + Copy + 'static> Subscriber<T> {
    /// The next message, if any (copied out: these are small).
    pub fn receive(&self) -> Result<Option<T>, BusError> {
        self.listener
            .try_wait(|_| {})
            .map_err(|e| err(format!("listener of {}", self.topic))(&e))?;
        Ok(self
            .subscriber
            .receive()
            .map_err(|e| err(format!("receive on {}", self.topic))(&e))?
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
    /// and holds an earlier frame.
    pub fn publish<E>(
        &self,
        header: FrameHeader,
        fill: impl FnOnce(&mut [u8], &mut [u8]) -> Result<(), E>,
    ) -> Result<Result<(), E>, BusError> {
        self.send_frame(header, true, fill)
    }

    /// As [`FramePublisher::publish`], but keeps `header` as given, with its
    /// recorded `published_ns` (replay).
    pub fn publish_as_recorded<E>(
        &self,
        header: FrameHeader,
        fill: impl FnOnce(&mut [u8], &mut [u8]) -> Result<(), E>,
    ) -> Result<Result<(), E>, BusError> {
        self.send_frame(header, false, fill)
    }

    fn send_frame<E>(
        &self,
        header: FrameHeader,
        stamp: bool,
        fill: impl FnOnce(&mut [u8], &mut [u8]) -> Result<(), E>,
    ) -> Result<Result<(), E>, BusError> {
        let len = header.image_len();
        // Uninitialised as far as the types go: `loan_slice` would zero-fill
        // the 600 KiB of a stereo frame on every loan, which cost more than
        // the whole hop did otherwise (see the IPC benchmark).
        let mut sample = self
            .publisher
            .loan_slice_uninit(2 * len)
            .map_err(|e| err("loan a frame")(&e))?;
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
        if let Err(e) = fill(left, right) {
            return Ok(Err(e));
        }
        if stamp {
            sample.user_header_mut().published_ns = now_ns();
        }
        // SAFETY: every byte is initialised (see above).
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(|e| err("send a frame")(&e))?;
        self.notifier
            .notify()
            .map_err(|e| err("notify a frame")(&e))?;
        Ok(Ok(()))
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
            .map_err(|e| err("frame listener")(&e))?;
        match self
            .subscriber
            .receive()
            .map_err(|e| err("receive a frame")(&e))?
        {
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
    /// passes, until it returns `false` or SIGINT/SIGTERM arrives (after
    /// which it runs once more, to take what is waiting).
    pub fn run(
        &self,
        listeners: &[&Listener<ipc::Service>],
        tick: Option<Duration>,
        mut on_wake: impl FnMut() -> bool,
    ) -> Result<(), BusError> {
        let mut guards = Vec::new();
        for l in listeners {
            guards.push(
                self.waitset
                    .attach_notification(*l)
                    .map_err(|e| err("attach a listener")(&e))?,
            );
        }
        let _interval = match tick {
            Some(period) => Some(
                self.waitset
                    .attach_interval(period)
                    .map_err(|e| err("attach an interval")(&e))?,
            ),
            None => None,
        };
        // Deliver anything that arrived before we attached.
        if !on_wake() {
            return Ok(());
        }
        let result = self
            .waitset
            .wait_and_process(|_| {
                if on_wake() {
                    CallbackProgression::Continue
                } else {
                    CallbackProgression::Stop
                }
            })
            .map_err(|e| err("waitset")(&e))?;
        // Stopped by a signal: handle what already arrived, so that a stage
        // stopped after its source has finished loses nothing.
        if matches!(
            result,
            WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest
        ) {
            on_wake();
        }
        drop(guards);
        Ok(())
    }
}
