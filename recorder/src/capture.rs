//! The IPC side of the recorder: subscribes to every topic of the
//! [`messages::topics`] table and hands each message, copied once out of
//! shared memory, to the writer.

use std::cell::Cell;
use std::sync::atomic::Ordering;

use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::ipc;
use messages::topics::{FrameTopic, SmallTopic, TopicId, TopicVisitor};
use messages::{Bus, BusError, FrameHeader, FrameSubscriber, Subscriber, now_ns};

use crate::channels::log_time;
use crate::writer::{Entry, RecorderHandle, WriterStopped};

/// Why capturing stopped.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// Receiving from shared memory failed.
    #[error("receiving")]
    Bus(#[from] BusError),
    /// The writer has stopped (its own error says why).
    #[error(transparent)]
    Writer(#[from] WriterStopped),
}

/// The recorder's subscription to one topic.
trait Tap {
    fn listener(&self) -> &Listener<ipc::Service>;
    /// Takes everything waiting to the writer; returns how many.
    fn drain(&self, out: &RecorderHandle) -> Result<usize, CaptureError>;
}

struct SmallTap<T: SmallTopic>(Subscriber<T>);

impl<T: SmallTopic> Tap for SmallTap<T> {
    fn listener(&self) -> &Listener<ipc::Service> {
        self.0.listener()
    }

    fn drain(&self, out: &RecorderHandle) -> Result<usize, CaptureError> {
        let mut n = 0;
        while let Some(m) = self.0.receive()? {
            out.send(Entry {
                topic: T::ID,
                log_time: log_time(T::stamp_ns(&m)),
                publish_time: log_time(now_ns()),
                data: bytemuck::bytes_of(&m).to_vec(),
            })?;
            n += 1;
        }
        Ok(n)
    }
}

struct FrameTap {
    topic: TopicId,
    subscriber: FrameSubscriber,
    last_seq: Cell<Option<u64>>,
}

impl Tap for FrameTap {
    fn listener(&self) -> &Listener<ipc::Service> {
        self.subscriber.listener()
    }

    fn drain(&self, out: &RecorderHandle) -> Result<usize, CaptureError> {
        let mut n = 0;
        while let Some((seq, stamp, data)) = self.subscriber.receive_with(|header, payload| {
            let mut data = Vec::with_capacity(size_of::<FrameHeader>() + payload.len());
            data.extend_from_slice(bytemuck::bytes_of(header));
            data.extend_from_slice(payload);
            (header.seq, header.stamp_ns, data)
        })? {
            let _span = tracing::trace_span!("record_frame", seq).entered();
            if let Some(last) = self.last_seq.get()
                && seq > last + 1
            {
                out.counters
                    .frames_missed
                    .fetch_add(seq - last - 1, Ordering::Relaxed);
            }
            self.last_seq.set(Some(seq));
            out.send(Entry {
                topic: self.topic,
                log_time: log_time(stamp),
                publish_time: log_time(now_ns()),
                data,
            })?;
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
        Ok(Box::new(FrameTap {
            topic: T::ID,
            subscriber: self.0.frame_subscriber::<T>()?,
            last_seq: Cell::new(None),
        }))
    }
}

/// Every subscription of the recorder: one per topic of the table.
pub struct Capture {
    /// Small-message topics first: they are cheap and never dropped.
    taps: Vec<Box<dyn Tap>>,
}

impl Capture {
    /// Subscribes to every topic on `bus`.
    pub fn new(bus: &Bus) -> Result<Self, BusError> {
        let (frames, small): (Vec<TopicId>, Vec<TopicId>) =
            TopicId::ALL.into_iter().partition(|t| t.carries_frames());
        let taps = small
            .into_iter()
            .chain(frames)
            .map(|t| t.visit(Subscribe(bus)))
            .collect::<Result<_, _>>()?;
        Ok(Self { taps })
    }

    /// The listeners to wake on.
    pub fn listeners(&self) -> Vec<&Listener<ipc::Service>> {
        self.taps.iter().map(|t| t.listener()).collect()
    }

    /// Takes everything waiting on every topic to the writer. Returns the
    /// number of messages taken, or why it cannot go on.
    pub fn drain(&self, out: &RecorderHandle) -> Result<usize, CaptureError> {
        let mut n = 0;
        for tap in &self.taps {
            n += tap.drain(out)?;
        }
        Ok(n)
    }
}
