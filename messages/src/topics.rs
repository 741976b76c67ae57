//! The topic table: every topic of the pipeline declared once, with its
//! name, its message type, how to read its stamp, and whether it carries
//! frames. Everything that handles "every topic" derives from it: the
//! services the launcher holds open (`runtime::Bus::open_all`), the
//! recorder's capture, channels and counters, and replay's publishers.
//!
//! Each topic is a marker type, so a port is typed by its topic and a name
//! and a type can never disagree (`runtime::Bus::publisher::<topics::JointState>()`
//! sends a [`crate::JointState`] and nothing else):
//!
//! ```
//! use messages::topics::{self, SmallTopic, Topic, TopicId};
//! assert_eq!(topics::JointState::ID, TopicId::JointState);
//! assert_eq!(TopicId::from_name("joint_state"), Some(TopicId::JointState));
//! let stamp = topics::JointState::stamp_ns(&messages::JointState { stamp_ns: 7, ..Default::default() });
//! assert_eq!(stamp, 7);
//! ```
//!
//! Code that must do something for every topic implements [`TopicVisitor`]
//! and walks [`TopicId::ALL`]; [`Message`] is a decoded message of any topic.

use std::fmt::Debug;

use bytemuck::Pod;
use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::{FrameError, FrameHeader};

/// A topic: its name on the bus (appended to the prefix) and in recordings.
pub trait Topic: 'static {
    /// Name on the bus and MCAP topic.
    const NAME: &'static str;
    /// Its entry in [`TopicId`].
    const ID: TopicId;
}

/// A topic of small fixed-size messages.
pub trait SmallTopic: Topic {
    /// The message type.
    type Message: ZeroCopySend + Pod + Debug + Default + Send;
    /// The message's stamp (CLOCK_MONOTONIC ns).
    fn stamp_ns(message: &Self::Message) -> i64;
}

/// A topic of stereo frames: a `[u8]` payload (left image then right image)
/// with a [`FrameHeader`] user header.
pub trait FrameTopic: Topic {
    /// Versioned type name of a recorded frame (header then both images).
    const TYPE_NAME: &'static str;
}

/// Something done for one topic, with its types known: walk
/// [`TopicId::ALL`] and call [`TopicId::visit`] to do it for every topic.
pub trait TopicVisitor {
    /// What visiting a topic gives.
    type Output;
    /// Called for a topic of small messages.
    fn small<T: SmallTopic>(self) -> Self::Output;
    /// Called for a topic of frames.
    fn frames<T: FrameTopic>(self) -> Self::Output;
}

/// Message encoding of the lossless MCAP channels (recordings, journals):
/// the `#[repr(C)]` bytes, little-endian, as laid out in shared memory.
pub const MESSAGE_ENCODING: &str = "x-mirror-repr-c";
/// Schema encoding of the lossless MCAP channels: a JSON [`Layout`].
pub const SCHEMA_ENCODING: &str = "x-mirror-layout+json";

/// What a message's bytes are, as recorded and as checked between hosts.
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

/// The versioned type name given in `#[type_name]`.
pub fn type_name_of<T: ZeroCopySend>() -> &'static str {
    // SAFETY: `type_name` only returns the string given in `#[type_name]`;
    // it is unsafe to implement, not to call.
    #[allow(unsafe_code)]
    unsafe {
        <T as ZeroCopySend>::type_name()
    }
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

struct LayoutOf;

impl TopicVisitor for LayoutOf {
    type Output = Layout;
    fn small<T: SmallTopic>(self) -> Layout {
        layout_of::<T::Message>()
    }
    fn frames<T: FrameTopic>(self) -> Layout {
        Layout {
            type_name: T::TYPE_NAME.into(),
            trailer: "left image then right image, height x stride bytes each".into(),
            ..layout_of::<FrameHeader>()
        }
    }
}

impl TopicId {
    /// The bus name of the topic, which is also its MCAP topic.
    pub fn name(self) -> &'static str {
        struct Name;
        impl TopicVisitor for Name {
            type Output = &'static str;
            fn small<T: SmallTopic>(self) -> &'static str {
                T::NAME
            }
            fn frames<T: FrameTopic>(self) -> &'static str {
                T::NAME
            }
        }
        self.visit(Name)
    }

    /// The topic with this name.
    pub fn from_name(name: &str) -> Option<TopicId> {
        TopicId::ALL.into_iter().find(|t| t.name() == name)
    }

    /// The layout of its messages.
    pub fn layout(self) -> Layout {
        self.visit(LayoutOf)
    }

    /// The schema data of its lossless MCAP channel: the layout as JSON.
    pub fn schema_data(self) -> Vec<u8> {
        serde_json::to_vec(&self.layout()).expect("a layout serialises")
    }

    /// Whether it carries frames.
    pub fn carries_frames(self) -> bool {
        struct Frames;
        impl TopicVisitor for Frames {
            type Output = bool;
            fn small<T: SmallTopic>(self) -> bool {
                false
            }
            fn frames<T: FrameTopic>(self) -> bool {
                true
            }
        }
        self.visit(Frames)
    }

    /// Its position in [`TopicId::ALL`] (for per-topic counters).
    pub fn index(self) -> usize {
        self as usize
    }
}

/// Layouts of earlier versions that recordings made with them still read
/// with: topic, type name, size. The later version only appended fields
/// to each, so a recorded message is read by zero-filling the rest, and
/// zero means "not stated" in every appended field.
const LEGACY_LAYOUTS: &[(TopicId, &str, usize)] = &[
    (TopicId::Calibration, "mirror.Calibration.v1", 328),
    (
        TopicId::Calibration,
        "mirror.Calibration.v2",
        std::mem::offset_of!(crate::CalibrationMsg, epoch),
    ),
    (TopicId::Located, "mirror.LocatedObject.v1", 48),
];

impl TopicId {
    /// How this build reads messages recorded with layout `found`: `Ok(None)`
    /// as they are (the current layout), `Ok(Some(size))` for an earlier
    /// layout of `size` bytes (see [`Message::decode_legacy`]); otherwise
    /// why not.
    pub fn recorded_as(self, found: &Layout) -> Result<Option<usize>, String> {
        let expected = self.layout();
        if found.type_name == expected.type_name && found.size == expected.size {
            return Ok(None);
        }
        LEGACY_LAYOUTS
            .iter()
            .find(|(topic, name, size)| {
                *topic == self && *name == found.type_name && *size == found.size
            })
            .map(|(_, _, size)| Some(*size))
            .ok_or_else(|| {
                format!(
                    "was recorded as {} ({} bytes); this build reads {} ({} bytes)",
                    found.type_name.escape_debug(),
                    found.size,
                    expected.type_name,
                    expected.size
                )
            })
    }
}

/// Why the bytes of a message do not decode ([`Message::decode`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// Fewer bytes than a frame's header.
    #[error("frame of {0} bytes has no header")]
    NoHeader(usize),
    /// Not the size of the message type (or of the frame header).
    #[error("{len} bytes where {expected} were expected")]
    Size {
        /// Bytes given.
        len: usize,
        /// Bytes of the type.
        expected: usize,
    },
    /// A frame whose header disagrees with its pixels.
    #[error(transparent)]
    Frame(#[from] FrameError),
}

fn read<T: Pod>(bytes: &[u8]) -> Result<T, DecodeError> {
    if bytes.len() != size_of::<T>() {
        return Err(DecodeError::Size {
            len: bytes.len(),
            expected: size_of::<T>(),
        });
    }
    Ok(bytemuck::pod_read_unaligned(bytes))
}

/// A `T` whose first `bytes.len()` bytes are `bytes` and the rest zero.
fn read_prefix<T: Pod>(bytes: &[u8]) -> Result<T, DecodeError> {
    if bytes.len() > size_of::<T>() {
        return Err(DecodeError::Size {
            len: bytes.len(),
            expected: size_of::<T>(),
        });
    }
    let mut value = T::zeroed();
    bytemuck::bytes_of_mut(&mut value)[..bytes.len()].copy_from_slice(bytes);
    Ok(value)
}

/// Declares the topics: marker types, [`TopicId`] and [`Message`].
macro_rules! topic_table {
    (
        frames: $(#[$fdoc:meta])* $frames:ident = $fname:literal, type_name $ftype:literal;
        $( $(#[$doc:meta])* $id:ident = $name:literal, $msg:ty, stamp |$m:ident| $stamp:expr; )*
    ) => {
        $(#[$fdoc])*
        #[derive(Debug, Clone, Copy)]
        pub struct $frames;

        impl Topic for $frames {
            const NAME: &'static str = $fname;
            const ID: TopicId = TopicId::$frames;
        }

        impl FrameTopic for $frames {
            const TYPE_NAME: &'static str = $ftype;
        }

        $(
            $(#[$doc])*
            #[derive(Debug, Clone, Copy)]
            pub struct $id;

            impl Topic for $id {
                const NAME: &'static str = $name;
                const ID: TopicId = TopicId::$id;
            }

            impl SmallTopic for $id {
                type Message = $msg;
                fn stamp_ns($m: &$msg) -> i64 {
                    $stamp
                }
            }
        )*

        /// Every topic, as a value (see the marker type of the same name).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub enum TopicId {
            #[doc = concat!("[`", stringify!($frames), "`]")]
            $frames,
            $(
                #[doc = concat!("[`", stringify!($id), "`]")]
                $id,
            )*
        }

        impl TopicId {
            /// How many topics there are.
            pub const COUNT: usize = 1 + [$(stringify!($id)),*].len();

            /// Every topic, in table order.
            pub const ALL: [TopicId; Self::COUNT] = [TopicId::$frames, $(TopicId::$id),*];

            /// Calls `visitor` with this topic's types.
            pub fn visit<V: TopicVisitor>(self, visitor: V) -> V::Output {
                match self {
                    TopicId::$frames => visitor.frames::<$frames>(),
                    $(TopicId::$id => visitor.small::<$id>(),)*
                }
            }
        }

        /// One message of any topic, decoded.
        // Decoded on the stack one at a time; boxing would allocate per message.
        #[allow(clippy::large_enum_variant)]
        #[derive(Debug, Clone, Copy, PartialEq)]
        pub enum Message<'a> {
            /// A stereo frame: header and both images.
            $frames(FrameHeader, &'a [u8]),
            $(
                #[doc = concat!("A message on [`", stringify!($id), "`].")]
                $id($msg),
            )*
        }

        impl<'a> Message<'a> {
            /// Decodes the bytes of a message on `topic` (a frame: its header
            /// then both images, checked against each other).
            pub fn decode(topic: TopicId, bytes: &'a [u8]) -> Result<Self, DecodeError> {
                Ok(match topic {
                    TopicId::$frames => {
                        let n = size_of::<FrameHeader>();
                        if bytes.len() < n {
                            return Err(DecodeError::NoHeader(bytes.len()));
                        }
                        let header: FrameHeader = read(&bytes[..n])?;
                        header.validate(bytes.len() - n)?;
                        Message::$frames(header, &bytes[n..])
                    }
                    $(TopicId::$id => Message::$id(read(bytes)?),)*
                })
            }

            /// Decodes a small message recorded with an earlier layout of
            /// `recorded_size` bytes (from [`TopicId::recorded_as`]): the
            /// fields the current layout appended read as zero.
            pub fn decode_legacy(
                topic: TopicId,
                bytes: &[u8],
                recorded_size: usize,
            ) -> Result<Message<'static>, DecodeError> {
                if bytes.len() != recorded_size {
                    return Err(DecodeError::Size {
                        len: bytes.len(),
                        expected: recorded_size,
                    });
                }
                Ok(match topic {
                    TopicId::$frames => return Err(DecodeError::NoHeader(bytes.len())),
                    $(TopicId::$id => Message::$id(read_prefix(bytes)?),)*
                })
            }

            /// The bytes it was decoded from: the inverse of [`Message::decode`].
            pub fn to_bytes(&self) -> Vec<u8> {
                match self {
                    Message::$frames(h, pixels) => [bytemuck::bytes_of(h), pixels].concat(),
                    $(Message::$id(m) => bytemuck::bytes_of(m).to_vec(),)*
                }
            }

            /// The bytes of a small message as they travel (`None` for a frame).
            pub fn small_bytes(&self) -> Option<&[u8]> {
                match self {
                    Message::$frames(..) => None,
                    $(Message::$id(m) => Some(bytemuck::bytes_of(m)),)*
                }
            }

            /// The topic it travels on.
            pub fn topic(&self) -> TopicId {
                match self {
                    Message::$frames(..) => TopicId::$frames,
                    $(Message::$id(_) => TopicId::$id,)*
                }
            }

            /// Moves every time it holds by `by_ns` (see [`crate::ShiftClock`]).
            pub fn shift_clock(&mut self, by_ns: i64) {
                use crate::ShiftClock;
                match self {
                    Message::$frames(h, _) => h.shift_clock(by_ns),
                    $(Message::$id(m) => m.shift_clock(by_ns),)*
                }
            }

            /// The message stamp (CLOCK_MONOTONIC ns).
            pub fn stamp_ns(&self) -> i64 {
                match self {
                    Message::$frames(h, _) => h.stamp_ns,
                    $(Message::$id(m) => <$id as SmallTopic>::stamp_ns(m),)*
                }
            }
        }
    };
}

topic_table! {
    frames:
        /// Stereo frames: `[u8]` (left image then right image) with a [`FrameHeader`].
        Frames = "frames", type_name "mirror.StereoFrame.v2";
    /// [`crate::StereoDetections`] of each frame.
    Detections = "detections", crate::StereoDetections, stamp |m| m.stamp_ns;
    /// The arm's [`crate::JointState`].
    JointState = "joint_state", crate::JointState, stamp |m| m.stamp_ns;
    /// Paired [`crate::MirrorSample`]s.
    Samples = "samples", crate::MirrorSample, stamp |m| m.stamp_ns;
    /// Each [`crate::CalibrationMsg`] of the mirror cameras.
    Calibration = "calibration", crate::CalibrationMsg, stamp |m| m.stamp_ns;
    /// Test samples' [`crate::Prediction`]s.
    Predictions = "predictions", crate::Prediction, stamp |m| m.stamp_ns;
    /// Objects located through the mirror, [`crate::LocatedObject`].
    Located = "located", crate::LocatedObject, stamp |m| m.stamp_ns;
    /// The arm driver's raw [`crate::JointPositions`].
    JointPositions = "joint_positions", crate::JointPositions, stamp |m| m.stamp_ns;
    /// The [`crate::PoseGoal`]s sent to the arm driver.
    PoseGoal = "pose_goal", crate::PoseGoal, stamp |m| m.stamp_ns;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_earlier_layout_is_the_current_ones_prefix_and_reads_zero_filled() {
        assert_eq!(
            std::mem::offset_of!(crate::CalibrationMsg, uncertainty),
            328
        );
        assert_eq!(
            std::mem::offset_of!(crate::LocatedObject, covariance_mm2),
            48
        );
        let v1 = |topic: TopicId| {
            let name = topic.layout().type_name.replace(".v2", ".v1");
            Layout {
                type_name: name.replace(".v3", ".v1"),
                size: LEGACY_LAYOUTS.iter().find(|l| l.0 == topic).unwrap().2,
                ..topic.layout()
            }
        };
        let located = crate::LocatedObject {
            stamp_ns: 5,
            revision: 2,
            id: 9,
            reserved: 0,
            position: [1.0, 2.0, 3.0],
            covariance_mm2: [4.0; 6],
        };
        let recorded = TopicId::Located.recorded_as(&v1(TopicId::Located)).unwrap();
        assert_eq!(recorded, Some(48));
        let bytes = &bytemuck::bytes_of(&located)[..48];
        let read = Message::decode_legacy(TopicId::Located, bytes, 48).unwrap();
        assert_eq!(
            read,
            Message::Located(crate::LocatedObject {
                covariance_mm2: [0.0; 6],
                ..located
            })
        );
        assert!(Message::decode_legacy(TopicId::Located, &bytes[..40], 48).is_err());
        assert_eq!(
            TopicId::Calibration.recorded_as(&TopicId::Calibration.layout()),
            Ok(None)
        );
        let calibration_v1 = v1(TopicId::Calibration);
        assert_eq!(
            TopicId::Calibration.recorded_as(&calibration_v1),
            Ok(Some(328))
        );
        let unknown = Layout {
            type_name: "mirror.Calibration.v0".into(),
            ..calibration_v1.clone()
        };
        let why = TopicId::Calibration.recorded_as(&unknown).unwrap_err();
        assert!(
            why.contains("mirror.Calibration.v0") && why.contains("v3"),
            "{why}"
        );
        // A v2 recording: the epoch reads zero (not stated).
        let v2_size = std::mem::offset_of!(crate::CalibrationMsg, epoch);
        let calibration_v2 = Layout {
            type_name: "mirror.Calibration.v2".into(),
            size: v2_size,
            ..calibration_v1
        };
        assert_eq!(
            TopicId::Calibration.recorded_as(&calibration_v2),
            Ok(Some(v2_size))
        );
        let current = crate::CalibrationMsg {
            revision: 4,
            epoch: crate::CalibrationEpoch {
                epoch: 2,
                ..Default::default()
            },
            ..Default::default()
        };
        let read = Message::decode_legacy(
            TopicId::Calibration,
            &bytemuck::bytes_of(&current)[..v2_size],
            v2_size,
        )
        .unwrap();
        assert_eq!(
            read,
            Message::Calibration(crate::CalibrationMsg {
                epoch: Default::default(),
                ..current
            })
        );
        assert!(
            TopicId::Samples
                .recorded_as(&v1(TopicId::Calibration))
                .is_err()
        );
    }

    #[test]
    fn every_topic_has_one_name_and_round_trips_its_bytes() {
        let mut names: Vec<_> = TopicId::ALL.iter().map(|t| t.name()).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), TopicId::ALL.len(), "names are unique");
        for (k, t) in TopicId::ALL.into_iter().enumerate() {
            assert_eq!(TopicId::from_name(t.name()), Some(t));
            assert_eq!(t.index(), k);
            assert_eq!(t.carries_frames(), t == TopicId::Frames);
        }
        let js = crate::JointState {
            seq: 3,
            stamp_ns: 42,
            dof: 4,
            q: [0.5; 8],
            ..Default::default()
        };
        let bytes = bytemuck::bytes_of(&js);
        let decoded = Message::decode(TopicId::JointState, bytes).unwrap();
        assert_eq!(decoded, Message::JointState(js));
        assert_eq!(decoded.to_bytes(), bytes);
        assert_eq!(decoded.stamp_ns(), 42);
        assert_eq!(decoded.topic(), TopicId::JointState);
        let mut shifted = decoded;
        shifted.shift_clock(-40);
        assert_eq!(shifted.stamp_ns(), 2);
        let err = Message::decode(TopicId::Detections, bytes).unwrap_err();
        assert!(err.to_string().contains("expected"), "{err}");
        assert_eq!(
            TopicId::JointState.layout().type_name,
            "mirror.JointState.v1"
        );
        assert_eq!(TopicId::Frames.layout().type_name, "mirror.StereoFrame.v2");
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
            encoding: crate::Encoding::Mono8 as u32,
        };
        let mut bytes = bytemuck::bytes_of(&header).to_vec();
        bytes.extend((0..16).map(|i| i as u8));
        match Message::decode(TopicId::Frames, &bytes).unwrap() {
            Message::Frames(h, pixels) => {
                assert_eq!(h, header);
                assert_eq!(pixels.len(), 16);
            }
            other => panic!("{other:?}"),
        }
        let mut shifted = Message::decode(TopicId::Frames, &bytes).unwrap();
        shifted.shift_clock(1000);
        match shifted {
            // An unknown time (0) stays unknown.
            Message::Frames(h, _) => assert_eq!((h.stamp_ns, h.published_ns), (1005, 0)),
            other => panic!("{other:?}"),
        }
        bytes.pop();
        assert!(Message::decode(TopicId::Frames, &bytes).is_err());
    }
}
