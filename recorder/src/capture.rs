//! The IPC side of the recorder: subscribes to every topic of the
//! [`messages::topics`] table and hands each message, copied once out of
//! shared memory, to the writer.

use std::cell::Cell;
use std::sync::atomic::Ordering;

use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::ipc;
use messages::now_ns;
use messages::topics::TopicId;
use runtime::{AnySubscriber, Bus, BusError};

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

/// The recorder's subscription to one topic, and the last frame it saw
/// (to count the frames it missed).
struct Tap {
    subscriber: AnySubscriber,
    last_seq: Cell<Option<u64>>,
}

impl Tap {
    /// Takes everything waiting to the writer; returns how many.
    fn drain(&self, out: &RecorderHandle) -> Result<usize, CaptureError> {
        let mut n = 0;
        while let Some(taken) = self.subscriber.take()? {
            let _span = taken
                .frame_seq
                .map(|seq| tracing::trace_span!("record_frame", seq).entered());
            if let Some(seq) = taken.frame_seq {
                if let Some(last) = self.last_seq.get()
                    && seq > last + 1
                {
                    out.counters
                        .frames_missed
                        .fetch_add(seq - last - 1, Ordering::Relaxed);
                }
                self.last_seq.set(Some(seq));
            }
            out.send(Entry {
                topic: self.subscriber.topic(),
                log_time: log_time(taken.stamp_ns),
                publish_time: log_time(now_ns()),
                data: taken.bytes,
            })?;
            n += 1;
        }
        Ok(n)
    }
}

/// Every subscription of the recorder: one per topic of the table.
pub struct Capture {
    /// Small-message topics first: they are cheap and never dropped.
    taps: Vec<Tap>,
}

impl Capture {
    /// Subscribes to every topic on `bus`.
    pub fn new(bus: &Bus) -> Result<Self, BusError> {
        let (frames, small): (Vec<TopicId>, Vec<TopicId>) =
            TopicId::ALL.into_iter().partition(|t| t.carries_frames());
        let taps = small
            .into_iter()
            .chain(frames)
            .map(|t| {
                Ok(Tap {
                    subscriber: AnySubscriber::new(bus, t)?,
                    last_seq: Cell::new(None),
                })
            })
            .collect::<Result<_, _>>()?;
        Ok(Self { taps })
    }

    /// The listeners to wake on.
    pub fn listeners(&self) -> Vec<&Listener<ipc::Service>> {
        self.taps.iter().map(|t| t.subscriber.listener()).collect()
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
