//! The IPC side of the recorder: subscribes to every topic of a pipeline
//! and hands each message, copied once out of shared memory, to the writer.

use std::sync::atomic::Ordering;

use messages::{
    Bus, CalibrationMsg, FrameHeader, JointState, LocatedObject, MirrorSample, Prediction,
    StereoDetections, Subscriber, now_ns, topics,
};

use crate::channels::{Topic, bytes_of, log_time};
use crate::writer::{Entry, RecorderHandle};

/// Every subscription of the recorder.
pub struct Capture {
    frames: messages::FrameSubscriber,
    detections: Subscriber<StereoDetections>,
    joints: Subscriber<JointState>,
    samples: Subscriber<MirrorSample>,
    calibrations: Subscriber<CalibrationMsg>,
    predictions: Subscriber<Prediction>,
    located: Subscriber<LocatedObject>,
    last_frame_seq: std::cell::Cell<Option<u64>>,
}

impl Capture {
    /// Subscribes to every topic on `bus`.
    pub fn new(bus: &Bus) -> Result<Self, messages::BusError> {
        Ok(Self {
            frames: bus.frame_subscriber(topics::FRAMES)?,
            detections: bus.subscriber(topics::DETECTIONS)?,
            joints: bus.subscriber(topics::JOINT_STATE)?,
            samples: bus.subscriber(topics::SAMPLES)?,
            calibrations: bus.subscriber(topics::CALIBRATION)?,
            predictions: bus.subscriber(topics::PREDICTIONS)?,
            located: bus.subscriber(topics::LOCATED)?,
            last_frame_seq: std::cell::Cell::new(None),
        })
    }

    /// The listeners to wake on.
    pub fn listeners(
        &self,
    ) -> Vec<&iceoryx2::port::listener::Listener<iceoryx2::prelude::ipc::Service>> {
        vec![
            self.frames.listener(),
            self.detections.listener(),
            self.joints.listener(),
            self.samples.listener(),
            self.calibrations.listener(),
            self.predictions.listener(),
            self.located.listener(),
        ]
    }

    /// Takes everything waiting on every topic to the writer. Returns the
    /// number of messages taken, or an error if the writer has stopped.
    pub fn drain(&self, out: &RecorderHandle) -> Result<usize, String> {
        let mut n = 0;
        n += drain_small(&self.detections, Topic::Detections, |m| m.stamp_ns, out)?;
        n += drain_small(&self.joints, Topic::JointState, |m| m.stamp_ns, out)?;
        n += drain_small(&self.samples, Topic::Samples, |m| m.stamp_ns, out)?;
        n += drain_small(&self.calibrations, Topic::Calibration, |m| m.stamp_ns, out)?;
        n += drain_small(&self.predictions, Topic::Predictions, |m| m.stamp_ns, out)?;
        n += drain_small(&self.located, Topic::Located, |m| m.stamp_ns, out)?;
        loop {
            let taken = self
                .frames
                .receive_with(|header, payload| {
                    let mut data = Vec::with_capacity(size_of::<FrameHeader>() + payload.len());
                    data.extend_from_slice(bytes_of(header));
                    data.extend_from_slice(payload);
                    (header.seq, header.stamp_ns, data)
                })
                .map_err(|e| e.to_string())?;
            let Some((seq, stamp, data)) = taken else {
                break;
            };
            let _span = tracing::trace_span!("record_frame", seq).entered();
            if let Some(last) = self.last_frame_seq.get()
                && seq > last + 1
            {
                out.counters
                    .frames_missed
                    .fetch_add(seq - last - 1, Ordering::Relaxed);
            }
            self.last_frame_seq.set(Some(seq));
            out.send(Entry {
                topic: Topic::Frames,
                log_time: log_time(stamp),
                publish_time: log_time(now_ns()),
                data,
            })
            .map_err(|e| e.to_string())?;
            n += 1;
        }
        Ok(n)
    }
}

fn drain_small<T: bytemuck::Pod + std::fmt::Debug + iceoryx2::prelude::ZeroCopySend>(
    subscriber: &Subscriber<T>,
    topic: Topic,
    stamp: impl Fn(&T) -> i64,
    out: &RecorderHandle,
) -> Result<usize, String> {
    let mut n = 0;
    while let Some(m) = subscriber.receive().map_err(|e| e.to_string())? {
        out.send(Entry {
            topic,
            log_time: log_time(stamp(&m)),
            publish_time: log_time(now_ns()),
            data: bytes_of(&m).to_vec(),
        })
        .map_err(|e| e.to_string())?;
        n += 1;
    }
    Ok(n)
}
