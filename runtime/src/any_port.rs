//! Ports for a topic known only at run time ([`TopicId`]): what replay and
//! the bridge between hosts publish decoded messages of any topic with, and
//! what the recorder and the bridge take every message of a topic with.

use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::ipc;

use messages::FrameHeader;
use messages::topics::{FrameTopic, Message, SmallTopic, TopicId, TopicVisitor};

use crate::{Bus, BusError, FramePublisher, FrameSubscriber, Publisher, Subscriber};

trait Republish {
    fn publish(&self, message: &Message<'_>) -> Result<(), BusError>;
}

struct Small<T: SmallTopic>(Publisher<T>);

impl<T: SmallTopic> Republish for Small<T> {
    fn publish(&self, message: &Message<'_>) -> Result<(), BusError> {
        let bytes = message.small_bytes().ok_or_else(|| wrong(T::ID, message))?;
        self.0.send(bytemuck::pod_read_unaligned(bytes))
    }
}

impl Republish for FramePublisher {
    fn publish(&self, message: &Message<'_>) -> Result<(), BusError> {
        let Message::Frames(header, pixels) = *message else {
            return Err(wrong(TopicId::Frames, message));
        };
        if pixels.len() != 2 * header.image_len() {
            return Err(BusError::WrongMessage(format!(
                "a frame of {} bytes whose header says {}",
                pixels.len(),
                2 * header.image_len()
            )));
        }
        self.publish_as_recorded(header, |left, right| {
            let (l, r) = pixels.split_at(left.len());
            left.copy_from_slice(l);
            right.copy_from_slice(r);
            Ok::<_, std::convert::Infallible>(true)
        })?
        .unwrap_or(true);
        Ok(())
    }
}

fn wrong(topic: TopicId, message: &Message<'_>) -> BusError {
    BusError::WrongMessage(format!(
        "a message of {} given to the publisher of {}",
        message.topic().name(),
        topic.name()
    ))
}

struct Advertise<'a> {
    bus: &'a Bus,
    max_frame_bytes: usize,
}

impl TopicVisitor for Advertise<'_> {
    type Output = Result<Box<dyn Republish>, BusError>;
    fn small<T: SmallTopic>(self) -> Self::Output {
        Ok(Box::new(Small(self.bus.publisher::<T>()?)))
    }
    fn frames<T: FrameTopic>(self) -> Self::Output {
        Ok(Box::new(
            self.bus.frame_publisher::<T>(self.max_frame_bytes.max(1))?,
        ))
    }
}

/// A publisher of one topic chosen at run time, publishing decoded
/// [`Message`]s as they were (a frame keeps its `published_ns`).
pub struct AnyPublisher {
    topic: TopicId,
    port: Box<dyn Republish>,
}

impl AnyPublisher {
    /// A publisher of `topic` on `bus`; frames of up to `max_frame_bytes`
    /// (both images) to begin with.
    pub fn new(bus: &Bus, topic: TopicId, max_frame_bytes: usize) -> Result<Self, BusError> {
        Ok(Self {
            topic,
            port: topic.visit(Advertise {
                bus,
                max_frame_bytes,
            })?,
        })
    }

    /// Its topic.
    pub fn topic(&self) -> TopicId {
        self.topic
    }

    /// Publishes `message`, which must be of this publisher's topic.
    pub fn publish(&self, message: &Message<'_>) -> Result<(), BusError> {
        self.port.publish(message)
    }
}

/// One message taken by an [`AnySubscriber`], copied out of shared memory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Taken {
    /// The message's stamp (CLOCK_MONOTONIC ns).
    pub stamp_ns: i64,
    /// A frame's sequence number (`None` for a small message).
    pub frame_seq: Option<u64>,
    /// Its bytes as laid out in shared memory (a frame: its header, then
    /// both images), what [`Message::decode`] reads.
    pub bytes: Vec<u8>,
}

trait Take {
    fn listener(&self) -> &Listener<ipc::Service>;
    fn take(&self) -> Result<Option<Taken>, BusError>;
}

impl<T: SmallTopic> Take for Subscriber<T> {
    fn listener(&self) -> &Listener<ipc::Service> {
        Subscriber::listener(self)
    }
    fn take(&self) -> Result<Option<Taken>, BusError> {
        Ok(self.receive()?.map(|m| Taken {
            stamp_ns: T::stamp_ns(&m),
            frame_seq: None,
            bytes: bytemuck::bytes_of(&m).to_vec(),
        }))
    }
}

impl Take for FrameSubscriber {
    fn listener(&self) -> &Listener<ipc::Service> {
        FrameSubscriber::listener(self)
    }
    fn take(&self) -> Result<Option<Taken>, BusError> {
        // The one copy out of shared memory that a file or a network needs.
        self.receive_with(|header, payload| {
            let mut bytes = Vec::with_capacity(size_of::<FrameHeader>() + payload.len());
            bytes.extend_from_slice(bytemuck::bytes_of(header));
            bytes.extend_from_slice(payload);
            Taken {
                stamp_ns: header.stamp_ns,
                frame_seq: Some(header.seq),
                bytes,
            }
        })
    }
}

struct Subscribe<'a>(&'a Bus);

impl TopicVisitor for Subscribe<'_> {
    type Output = Result<Box<dyn Take>, BusError>;
    fn small<T: SmallTopic>(self) -> Self::Output {
        Ok(Box::new(self.0.subscriber::<T>()?))
    }
    fn frames<T: FrameTopic>(self) -> Self::Output {
        Ok(Box::new(self.0.frame_subscriber::<T>()?))
    }
}

/// A subscriber to one topic chosen at run time, taking each message as
/// its bytes.
pub struct AnySubscriber {
    topic: TopicId,
    port: Box<dyn Take>,
}

impl AnySubscriber {
    /// A subscriber to `topic` on `bus`.
    pub fn new(bus: &Bus, topic: TopicId) -> Result<Self, BusError> {
        Ok(Self {
            topic,
            port: topic.visit(Subscribe(bus))?,
        })
    }

    /// Its topic.
    pub fn topic(&self) -> TopicId {
        self.topic
    }

    /// The listener to wake on.
    pub fn listener(&self) -> &Listener<ipc::Service> {
        self.port.listener()
    }

    /// The oldest waiting message, if any.
    pub fn take(&self) -> Result<Option<Taken>, BusError> {
        self.port.take()
    }
}
