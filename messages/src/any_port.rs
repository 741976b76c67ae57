//! Ports for a topic known only at run time ([`TopicId`]): what replay and
//! the bridge between hosts publish decoded messages of any topic with.

use crate::topics::{FrameTopic, Message, SmallTopic, TopicId, TopicVisitor};
use crate::{Bus, BusError, FramePublisher, Publisher};

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
            return Err(BusError::new(format!(
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
    BusError::new(format!(
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
