//! `replay export --ros2 DIR`: a recording as a rosbag2 bag (MCAP storage)
//! that `ros2 bag play`, rosbag2 readers and Foxglove open:
//!
//! | recording | bag topic | type |
//! |---|---|---|
//! | `joint_positions` | `/joint_states` | `sensor_msgs/JointState` (the rig's joint names; rad, m) |
//! | `frames` | `/left/image_raw`, `/right/image_raw` | `sensor_msgs/Image` (mono8) |
//! | `frames` | `/left/camera_info`, `/right/camera_info` | `sensor_msgs/CameraInfo` (the rig's intrinsics) |
//! | `calibration` | `/tf_static` | `tf2_msgs/TFMessage` (TRANSIENT_LOCAL) |
//! | `located` | `/mirror/located` | `geometry_msgs/PointStamped` |
//!
//! Stamps and log times are wall clock: the recording's monotonic stamps
//! plus the offset between the clocks its recorder noted when it started
//! (`wall_minus_monotonic_ns` in the `run` metadata). The other topics have
//! no ROS type and are counted as not exported.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use geometry::{JointKind, Rig};
use messages::topics::Message;
use ros2_proc::bag::{BagError, BagWriter};
use ros2_proc::msgs::{self, CameraInfo, Header, Image};
use ros2_proc::wire::Qos;

use crate::reader::{ReadError, Recording};

/// Why a recording could not be exported.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The recording.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The bag.
    #[error(transparent)]
    Bag(#[from] BagError),
    /// The rig could not be read from the recording.
    #[error("{}: {why}", recording.display())]
    Rig {
        /// The recording.
        recording: PathBuf,
        /// What is wrong.
        why: String,
    },
}

/// What was exported.
#[derive(Debug, Clone, PartialEq)]
pub struct Exported {
    /// Messages per bag topic.
    pub topics: BTreeMap<String, u64>,
    /// Recorded messages per topic that have no ROS type.
    pub not_exported: BTreeMap<&'static str, u64>,
    /// The offset used from our stamps to wall-clock time, ns (`None`: the
    /// recording noted none, and stamps stay on the recording host's
    /// monotonic clock).
    pub wall_minus_monotonic_ns: Option<i64>,
    /// The bag's MCAP file.
    pub file: PathBuf,
}

/// Topics of the bag.
pub const JOINT_STATES: &str = "/joint_states";
/// The images, left and right.
pub const IMAGES: [&str; 2] = ["/left/image_raw", "/right/image_raw"];
/// The camera infos, left and right.
pub const CAMERA_INFOS: [&str; 2] = ["/left/camera_info", "/right/camera_info"];
/// The calibration's frames.
pub const TF_STATIC: &str = "/tf_static";
/// The located objects.
pub const LOCATED: &str = "/mirror/located";

/// Camera drivers' QoS (`SensorDataQoS`: best effort, depth 5).
const SENSOR_DATA: Qos = Qos {
    reliable: false,
    transient_local: false,
    depth: 5,
};

/// The rig the recording holds: its `rig.toml` attachment and the files it
/// refers to, unpacked into a temporary directory and read.
fn rig_of(recording: &Recording) -> Result<Rig, ExportError> {
    let fail = |why: String| ExportError::Rig {
        recording: recording.path().to_path_buf(),
        why,
    };
    let extras = recording.extras()?;
    if !extras.attachments.iter().any(|(n, _)| n == "rig.toml") {
        return Err(fail(
            "no rig attached (record with `recorder --rig`, as the pipeline does)".into(),
        ));
    }
    let dir = tempfile::tempdir().map_err(|e| fail(format!("cannot unpack the rig: {e}")))?;
    for (name, data) in &extras.attachments {
        // Only a plain file name: an attachment cannot write elsewhere.
        if Path::new(name)
            .file_name()
            .is_some_and(|b| b == name.as_str())
        {
            std::fs::write(dir.path().join(name), data)
                .map_err(|e| fail(format!("cannot unpack {name}: {e}")))?;
        }
    }
    formats::rig::read(dir.path().join("rig.toml")).map_err(|e| fail(format!("attached rig: {e}")))
}

/// A camera's intrinsics as the `CameraInfo` its driver would publish (no
/// rectification: `R` identity, `P` = `K` with a zero fourth column).
fn camera_info(rig: &Rig, k: usize, header: Header) -> CameraInfo {
    let i = rig.cameras[k].intrinsics;
    let d = i.dist.coefficients();
    CameraInfo {
        header,
        height: i.height,
        width: i.width,
        distortion_model: i.dist.model().ros_name().into(),
        d,
        k: [i.fx, i.skew, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            i.fx, i.skew, i.cx, 0.0, 0.0, i.fy, i.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        ..Default::default()
    }
}

/// Writes `recording` as a rosbag2 bag into the new directory `out`.
pub fn export_ros2(recording: &Recording, out: &Path) -> Result<Exported, ExportError> {
    let rig = rig_of(recording)?;
    let (joints, kinds) = rig.arm.as_ref().map_or((Vec::new(), Vec::new()), |a| {
        (a.joint_names(), a.joint_kinds())
    });
    let offset = recording
        .extras()?
        .metadata
        .get("run")
        .and_then(|run| run.get("wall_minus_monotonic_ns"))
        .and_then(|v| v.parse::<i64>().ok());
    let wall = |stamp_ns: i64| stamp_ns.saturating_add(offset.unwrap_or(0));
    let mut bag = BagWriter::create(out)?;
    let mut not_exported: BTreeMap<&'static str, u64> = BTreeMap::new();
    recording.for_each(|_, message| {
        let at = wall(message.stamp_ns());
        let time = at.max(0) as u64;
        match message {
            Message::JointPositions(p) => {
                let n = p.joints().len().min(joints.len());
                let names: Vec<String> = if joints.is_empty() {
                    (1..=p.joints().len())
                        .map(|i| format!("joint{i}"))
                        .collect()
                } else {
                    joints[..n].to_vec()
                };
                let kinds = if kinds.is_empty() {
                    vec![JointKind::Revolute; names.len()]
                } else {
                    kinds[..names.len()].to_vec()
                };
                let state =
                    ros2_proc::arm::joint_state_of(&p.joints()[..names.len()], &names, &kinds, at);
                bag.write(JOINT_STATES, Qos::reliable(10), time, &state)?;
            }
            Message::Frames(h, pixels) => {
                let len = h.image_len();
                for k in 0..2 {
                    let header = Header {
                        stamp: msgs::Time::from_ns(at),
                        frame_id: formats::export::CAMERA_FRAMES[k].into(),
                    };
                    let image = Image {
                        header: header.clone(),
                        height: h.height,
                        width: h.width,
                        encoding: "mono8".into(),
                        is_bigendian: 0,
                        step: h.stride,
                        data: pixels[k * len..(k + 1) * len].to_vec(),
                    };
                    bag.write(IMAGES[k], SENSOR_DATA, time, &image)?;
                    bag.write(
                        CAMERA_INFOS[k],
                        SENSOR_DATA,
                        time,
                        &camera_info(&rig, k, header),
                    )?;
                }
            }
            Message::Calibration(c) => {
                let tf = ros2_proc::tf::transforms_of(&c, &rig, at);
                bag.write(TF_STATIC, Qos::LATCHED, time, &tf)?;
            }
            Message::Located(o) => {
                let point = ros2_proc::tf::point_of(&o, at);
                bag.write(LOCATED, Qos::reliable(10), time, &point)?;
            }
            other => *not_exported.entry(other.topic().name()).or_default() += 1,
        }
        Ok::<_, ExportError>(true)
    })?;
    let summary = bag.finish()?;
    Ok(Exported {
        topics: summary.counts,
        not_exported,
        wall_minus_monotonic_ns: offset,
        file: summary.file,
    })
}
