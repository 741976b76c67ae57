//! The lossless channels: one per bus topic, holding the message bytes
//! exactly as they travel in shared memory, with a schema that names the
//! type and its layout so that a reader can refuse a layout it does not know.

use bytemuck::Pod;
use iceoryx2::prelude::ZeroCopySend;
use messages::{
    CalibrationMsg, FrameHeader, JointState, LocatedObject, MirrorSample, Prediction,
    StereoDetections, topics,
};
use serde::{Deserialize, Serialize};

/// Message encoding of the lossless channels: the `#[repr(C)]` bytes,
/// little-endian, as laid out in shared memory.
pub const MESSAGE_ENCODING: &str = "x-mirror-repr-c";
/// Schema encoding of the lossless channels: a JSON [`Layout`].
pub const SCHEMA_ENCODING: &str = "x-mirror-layout+json";
/// Type name of a recorded stereo frame: a [`FrameHeader`] then both images.
pub const FRAME_TYPE_NAME: &str = "mirror.StereoFrame.v2";

/// A bus topic as recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Topic {
    /// Stereo frames.
    Frames,
    /// [`StereoDetections`].
    Detections,
    /// [`JointState`].
    JointState,
    /// [`MirrorSample`].
    Samples,
    /// [`CalibrationMsg`].
    Calibration,
    /// [`Prediction`].
    Predictions,
    /// [`LocatedObject`].
    Located,
}

/// What a lossless channel's schema says about its bytes.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Layout {
    /// Versioned type name, e.g. `mirror.JointState.v1`.
    pub type_name: String,
    /// Size of the fixed part in bytes.
    pub size: usize,
    /// Alignment of the type in shared memory.
    pub align: usize,
    /// Always `little`: the machines we run on.
    pub byte_order: String,
    /// What follows the fixed part, if anything.
    pub trailer: String,
}

fn type_name_of<T: ZeroCopySend>() -> &'static str {
    // SAFETY: `type_name` only returns the string given in `#[type_name]`;
    // it is unsafe to implement, not to call.
    unsafe { <T as ZeroCopySend>::type_name() }
}

fn layout_of<T: ZeroCopySend + Pod>() -> Layout {
    Layout {
        type_name: type_name_of::<T>().to_string(),
        size: size_of::<T>(),
        align: align_of::<T>(),
        byte_order: "little".into(),
        trailer: String::new(),
    }
}

impl Topic {
    /// Every topic, in a fixed order.
    pub const ALL: [Topic; 7] = [
        Topic::Frames,
        Topic::Detections,
        Topic::JointState,
        Topic::Samples,
        Topic::Calibration,
        Topic::Predictions,
        Topic::Located,
    ];

    /// The bus topic name, which is also the MCAP topic.
    pub fn name(self) -> &'static str {
        match self {
            Topic::Frames => topics::FRAMES,
            Topic::Detections => topics::DETECTIONS,
            Topic::JointState => topics::JOINT_STATE,
            Topic::Samples => topics::SAMPLES,
            Topic::Calibration => topics::CALIBRATION,
            Topic::Predictions => topics::PREDICTIONS,
            Topic::Located => topics::LOCATED,
        }
    }

    /// The topic with this bus name.
    pub fn from_name(name: &str) -> Option<Topic> {
        Topic::ALL.into_iter().find(|t| t.name() == name)
    }

    /// The layout this build writes and reads.
    pub fn layout(self) -> Layout {
        match self {
            Topic::Frames => Layout {
                type_name: FRAME_TYPE_NAME.into(),
                trailer: "left image then right image, height x stride bytes each".into(),
                ..layout_of::<FrameHeader>()
            },
            Topic::Detections => layout_of::<StereoDetections>(),
            Topic::JointState => layout_of::<JointState>(),
            Topic::Samples => layout_of::<MirrorSample>(),
            Topic::Calibration => layout_of::<CalibrationMsg>(),
            Topic::Predictions => layout_of::<Prediction>(),
            Topic::Located => layout_of::<LocatedObject>(),
        }
    }

    /// The schema data: the layout as JSON.
    pub fn schema_data(self) -> Vec<u8> {
        serde_json::to_vec(&self.layout()).expect("a layout serialises")
    }
}

/// One recorded message, decoded.
// Decoded on the stack one at a time; boxing the detections would allocate per message.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Message<'a> {
    /// A stereo frame: header and both images.
    Frame(FrameHeader, &'a [u8]),
    /// Detections of one stereo frame.
    Detections(StereoDetections),
    /// A joint state.
    JointState(JointState),
    /// A paired sample.
    Sample(MirrorSample),
    /// A calibration.
    Calibration(CalibrationMsg),
    /// A prediction.
    Prediction(Prediction),
    /// A located object.
    Located(LocatedObject),
}

fn read<T: Pod>(bytes: &[u8]) -> Result<T, String> {
    if bytes.len() != size_of::<T>() {
        return Err(format!(
            "{} bytes where {} were expected",
            bytes.len(),
            size_of::<T>()
        ));
    }
    Ok(bytemuck::pod_read_unaligned(bytes))
}

impl<'a> Message<'a> {
    /// Decodes the bytes of a message on `topic`.
    pub fn decode(topic: Topic, bytes: &'a [u8]) -> Result<Self, String> {
        Ok(match topic {
            Topic::Frames => {
                let n = size_of::<FrameHeader>();
                if bytes.len() < n {
                    return Err(format!("frame of {} bytes has no header", bytes.len()));
                }
                let header: FrameHeader = read(&bytes[..n])?;
                header.validate(bytes.len() - n)?;
                Message::Frame(header, &bytes[n..])
            }
            Topic::Detections => Message::Detections(read(bytes)?),
            Topic::JointState => Message::JointState(read(bytes)?),
            Topic::Samples => Message::Sample(read(bytes)?),
            Topic::Calibration => Message::Calibration(read(bytes)?),
            Topic::Predictions => Message::Prediction(read(bytes)?),
            Topic::Located => Message::Located(read(bytes)?),
        })
    }

    /// The bytes it was decoded from: the inverse of [`Message::decode`].
    pub fn to_bytes(&self) -> Vec<u8> {
        match self {
            Message::Frame(h, pixels) => [bytes_of(h), pixels].concat(),
            Message::Detections(m) => bytes_of(m).to_vec(),
            Message::JointState(m) => bytes_of(m).to_vec(),
            Message::Sample(m) => bytes_of(m).to_vec(),
            Message::Calibration(m) => bytes_of(m).to_vec(),
            Message::Prediction(m) => bytes_of(m).to_vec(),
            Message::Located(m) => bytes_of(m).to_vec(),
        }
    }

    /// The topic it travels on.
    pub fn topic(&self) -> Topic {
        match self {
            Message::Frame(..) => Topic::Frames,
            Message::Detections(_) => Topic::Detections,
            Message::JointState(_) => Topic::JointState,
            Message::Sample(_) => Topic::Samples,
            Message::Calibration(_) => Topic::Calibration,
            Message::Prediction(_) => Topic::Predictions,
            Message::Located(_) => Topic::Located,
        }
    }

    /// The message stamp (CLOCK_MONOTONIC ns), which is the MCAP log time.
    pub fn stamp_ns(&self) -> i64 {
        match self {
            Message::Frame(h, _) => h.stamp_ns,
            Message::Detections(m) => m.stamp_ns,
            Message::JointState(m) => m.stamp_ns,
            Message::Sample(m) => m.stamp_ns,
            Message::Calibration(m) => m.stamp_ns,
            Message::Prediction(m) => m.stamp_ns,
            Message::Located(m) => m.stamp_ns,
        }
    }
}

/// Log time of a stamp: stamps before the clock's epoch (malformed) map to 0.
pub fn log_time(stamp_ns: i64) -> u64 {
    stamp_ns.max(0) as u64
}

/// The bytes of a fixed-size message, as recorded.
pub fn bytes_of<T: Pod>(message: &T) -> &[u8] {
    bytemuck::bytes_of(message)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_topic_round_trips_its_bytes() {
        let js = JointState {
            seq: 3,
            stamp_ns: 42,
            dof: 4,
            q: [0.5; 8],
            ..Default::default()
        };
        let decoded = Message::decode(Topic::JointState, bytes_of(&js)).unwrap();
        assert_eq!(decoded, Message::JointState(js));
        assert_eq!(decoded.to_bytes(), bytes_of(&js));
        assert_eq!(decoded.stamp_ns(), 42);
        let err = Message::decode(Topic::Detections, bytes_of(&js)).unwrap_err();
        assert!(err.contains("expected"), "{err}");
        for t in Topic::ALL {
            assert_eq!(Topic::from_name(t.name()), Some(t));
            let layout: Layout = serde_json::from_slice(&t.schema_data()).unwrap();
            assert_eq!(layout, t.layout());
        }
    }

    #[test]
    fn a_frame_is_its_header_then_both_images() {
        let header = FrameHeader {
            seq: 1,
            stamp_ns: 5,
            published_ns: 0,
            width: 4,
            height: 2,
            stride: 4,
            encoding: messages::encoding::MONO8,
        };
        let mut bytes = bytes_of(&header).to_vec();
        bytes.extend((0..16).map(|i| i as u8));
        match Message::decode(Topic::Frames, &bytes).unwrap() {
            Message::Frame(h, pixels) => {
                assert_eq!(h, header);
                assert_eq!(pixels.len(), 16);
            }
            other => panic!("{other:?}"),
        }
        bytes.pop();
        assert!(Message::decode(Topic::Frames, &bytes).is_err());
    }
}
