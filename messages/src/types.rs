//! The message types. Units: mm, rad, px, ns (`i64`, CLOCK_MONOTONIC).

use bytemuck::{Pod, Zeroable};
use iceoryx2::prelude::ZeroCopySend;
use nalgebra::{Matrix3, Vector2, Vector3};

/// Most markers reported per camera image.
pub const MAX_MARKERS: usize = 16;
/// Most joints in a joint state.
pub const MAX_JOINTS: usize = 8;
/// Largest marker id accepted (the largest ArUco dictionary has 1024).
pub const MAX_MARKER_ID: u32 = 1023;
/// Largest image side accepted, px.
pub const MAX_IMAGE_SIDE: u32 = 4096;

pub use geometry::Role;

/// Pixel encoding of a frame. The discriminants are the wire and recording
/// values ([`FrameHeader::encoding`]): never reorder them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum Encoding {
    /// 8-bit grey.
    Mono8 = 0,
    /// 8-bit blue, green, red.
    Bgr8 = 1,
}

impl Encoding {
    /// Every encoding.
    pub const ALL: [Encoding; 2] = [Encoding::Mono8, Encoding::Bgr8];

    /// Bytes per pixel.
    pub fn bytes_per_pixel(self) -> u32 {
        match self {
            Encoding::Mono8 => 1,
            Encoding::Bgr8 => 3,
        }
    }
}

geometry::try_from_u32!(Encoding);

/// Motion phase of the arm. The discriminants are the wire and recording
/// values ([`JointState::phase`]): never reorder them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum Phase {
    /// Moving between poses.
    Moving = 0,
    /// Holding still at a pose.
    Settled = 1,
    /// The pose plan is finished.
    Done = 2,
}

impl Phase {
    /// Every phase.
    pub const ALL: [Phase; 3] = [Phase::Moving, Phase::Settled, Phase::Done];
}

geometry::try_from_u32!(Phase);

/// User header of a stereo frame; the payload holds the left then the right
/// image, each `height * stride` bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.FrameHeader.v2")]
#[repr(C)]
pub struct FrameHeader {
    /// Frame sequence number.
    pub seq: u64,
    /// Capture time, ns.
    pub stamp_ns: i64,
    /// When the frame was handed to the pipeline (published into shared
    /// memory), ns: where the pipeline's own latency starts.
    pub published_ns: i64,
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Bytes per image row.
    pub stride: u32,
    /// [`Encoding`] of both images.
    pub encoding: u32,
}

impl FrameHeader {
    /// Bytes per pixel of the encoding, if known.
    pub fn bytes_per_pixel(&self) -> Option<u32> {
        Encoding::try_from(self.encoding)
            .ok()
            .map(Encoding::bytes_per_pixel)
    }

    /// Bytes of one image.
    pub fn image_len(&self) -> usize {
        self.height as usize * self.stride as usize
    }

    /// Checks the header against the payload length; says what is wrong.
    pub fn validate(&self, payload_len: usize) -> Result<(), FrameError> {
        let bpp = self
            .bytes_per_pixel()
            .ok_or(FrameError::UnknownEncoding(self.encoding))?;
        if self.width == 0
            || self.height == 0
            || self.width > MAX_IMAGE_SIDE
            || self.height > MAX_IMAGE_SIDE
        {
            return Err(FrameError::ImageSize {
                width: self.width,
                height: self.height,
            });
        }
        if self.stride < self.width * bpp {
            return Err(FrameError::Stride {
                stride: self.stride,
                width: self.width,
                bytes_per_pixel: bpp,
            });
        }
        if payload_len != 2 * self.image_len() {
            return Err(FrameError::Payload {
                len: payload_len,
                expected: 2 * self.image_len(),
            });
        }
        Ok(())
    }
}

/// What is wrong with a frame's header, checked against its payload
/// ([`FrameHeader::validate`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// [`FrameHeader::encoding`] is no [`Encoding`].
    #[error("unknown encoding {0}")]
    UnknownEncoding(u32),
    /// A side is 0 or above [`MAX_IMAGE_SIDE`].
    #[error("image size {width}x{height} out of range")]
    ImageSize {
        /// Image width, px.
        width: u32,
        /// Image height, px.
        height: u32,
    },
    /// Rows shorter than the image's width.
    #[error("stride {stride} below width {width} x {bytes_per_pixel}")]
    Stride {
        /// Bytes per image row.
        stride: u32,
        /// Image width, px.
        width: u32,
        /// Bytes per pixel of the encoding.
        bytes_per_pixel: u32,
    },
    /// The payload is not two images of the header's size.
    #[error("payload of {len} bytes, expected {expected}")]
    Payload {
        /// Bytes of the payload.
        len: usize,
        /// Bytes of two images.
        expected: usize,
    },
}

/// One marker found in one image.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.Marker.v1")]
#[repr(C)]
pub struct Marker {
    /// Marker id in its dictionary.
    pub id: u32,
    /// 1 if seen mirror-reversed, else 0.
    pub mirrored: u32,
    /// Corners as detected (x0, y0, ... x3, y3), px.
    pub corners: [f64; 8],
    /// Intersection of the diagonals, px.
    pub center: [f64; 2],
}

/// The markers found in one camera image.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.CameraMarkers.v1")]
#[repr(C)]
pub struct CameraMarkers {
    /// Valid entries in `markers`.
    pub count: u32,
    /// Markers dropped for lack of room.
    pub overflow: u32,
    /// The markers.
    pub markers: [Marker; MAX_MARKERS],
}

impl CameraMarkers {
    /// The valid markers.
    pub fn iter(&self) -> impl Iterator<Item = &Marker> {
        self.markers
            .iter()
            .take((self.count as usize).min(MAX_MARKERS))
    }

    /// Adds a marker, or counts it as overflow.
    pub fn push(&mut self, m: Marker) {
        if (self.count as usize) < MAX_MARKERS {
            self.markers[self.count as usize] = m;
            self.count += 1;
        } else {
            self.overflow += 1;
        }
    }

    /// The marker with `id` and mirror flag, if found.
    pub fn find(&self, id: u32, mirrored: bool) -> Option<&Marker> {
        self.iter()
            .find(|m| m.id == id && (m.mirrored != 0) == mirrored)
    }
}

/// Detections of one stereo frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.StereoDetections.v2")]
#[repr(C)]
pub struct StereoDetections {
    /// The frame's sequence number.
    pub seq: u64,
    /// The frame's capture time, ns.
    pub stamp_ns: i64,
    /// The frame's [`FrameHeader::published_ns`].
    pub frame_published_ns: i64,
    /// Left then right.
    pub cameras: [CameraMarkers; 2],
}

impl StereoDetections {
    /// What makes this message unusable, if anything (stamps are the
    /// receiver's to judge).
    pub fn fault(&self) -> Option<String> {
        for (k, c) in self.cameras.iter().enumerate() {
            if c.count as usize > MAX_MARKERS {
                return Some(format!("camera {k}: {} markers", c.count));
            }
            for m in c.iter() {
                if !m
                    .center
                    .iter()
                    .chain(m.corners.iter())
                    .all(|v| v.is_finite())
                {
                    return Some(format!("camera {k}: marker {}: non-finite corner", m.id));
                }
                if m.id > MAX_MARKER_ID || m.mirrored > 1 {
                    return Some(format!(
                        "camera {k}: marker id {} (mirrored {}) out of range",
                        m.id, m.mirrored
                    ));
                }
            }
        }
        None
    }
}

/// The arm's joint state and the end-effector model's prediction.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.JointState.v1")]
#[repr(C)]
pub struct JointState {
    /// Message sequence number.
    pub seq: u64,
    /// Time of the reading, ns.
    pub stamp_ns: i64,
    /// Pose id of the plan (the pose being moved to or held).
    pub pose: u64,
    /// [`Phase`].
    pub phase: u32,
    /// [`Role`] of the pose.
    pub role: u32,
    /// Valid entries in `q`.
    pub dof: u32,
    /// Explicit padding (keeps `q` 8-byte aligned without implicit padding).
    pub reserved: u32,
    /// Joint readings, rad.
    pub q: [f64; MAX_JOINTS],
    /// End-effector model's position `J` for `q`, mm (world).
    pub model_point: [f64; 3],
}

impl JointState {
    /// The valid joint readings.
    pub fn joints(&self) -> &[f64] {
        &self.q[..(self.dof as usize).min(MAX_JOINTS)]
    }

    /// What makes this message unusable for an arm of `dof` joints, if
    /// anything (stamps are the receiver's to judge).
    pub fn fault(&self, dof: usize) -> Option<String> {
        if self.dof as usize > MAX_JOINTS || self.dof as usize != dof {
            return Some(format!("{} joints, the arm has {dof}", self.dof));
        }
        let finite = self
            .joints()
            .iter()
            .chain(self.model_point.iter())
            .all(|v| v.is_finite());
        if !finite {
            return Some("non-finite joint angle or model point".into());
        }
        if Phase::try_from(self.phase).is_err() || Role::try_from(self.role).is_err() {
            return Some(format!(
                "phase {} or role {} unknown",
                self.phase, self.role
            ));
        }
        None
    }

    /// The phase, or the unknown wire value.
    pub fn phase(&self) -> Result<Phase, u32> {
        Phase::try_from(self.phase)
    }

    /// The pose's role, or the unknown wire value.
    pub fn role(&self) -> Result<Role, u32> {
        Role::try_from(self.role)
    }
}

/// One paired sample: a settled pose and the first stereo detection after it.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.MirrorSample.v1")]
#[repr(C)]
pub struct MirrorSample {
    /// Pose id.
    pub pose: u64,
    /// Stamp of the detection used, ns.
    pub stamp_ns: i64,
    /// [`Role`] of the pose.
    pub role: u32,
    /// Valid entries in `q`.
    pub dof: u32,
    /// Joint readings, rad.
    pub q: [f64; MAX_JOINTS],
    /// The model's `J`, mm.
    pub model_point: [f64; 3],
    /// Marker centre, left then right (u, v), px.
    pub pixels: [[f64; 2]; 2],
    /// Triangulated through the real cameras (`Ĵ` for mirror views), mm.
    pub triangulated: [f64; 3],
}

impl MirrorSample {
    /// As a geometry sample (for the solvers and evaluation).
    pub fn to_sample(&self) -> geometry::Sample {
        geometry::Sample {
            pose: self.pose,
            view: if self.role == Role::Direct as u32 {
                geometry::View::Direct
            } else {
                geometry::View::Mirror
            },
            joints: Some(self.q[..(self.dof as usize).min(MAX_JOINTS)].to_vec()),
            model_point: Some(Vector3::from(self.model_point)),
            pixels: self.pixels.map(Vector2::from),
        }
    }
}

/// A mirror-perspective camera's pose.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.CameraPose.v1")]
#[repr(C)]
pub struct CameraPose {
    /// Row-major `R` (camera from world).
    pub camera_from_world: [f64; 9],
    /// Centre in world, mm.
    pub center: [f64; 3],
}

impl CameraPose {
    /// From a camera.
    pub fn from_camera(c: &geometry::Camera) -> Self {
        let mut r = [0.0; 9];
        for i in 0..3 {
            for j in 0..3 {
                r[3 * i + j] = c.camera_from_world[(i, j)];
            }
        }
        Self {
            camera_from_world: r,
            center: c.center.into(),
        }
    }

    /// To a camera with the given intrinsics.
    pub fn to_camera(&self, intrinsics: geometry::Intrinsics) -> geometry::Camera {
        geometry::Camera::new(
            intrinsics,
            Matrix3::from_row_slice(&self.camera_from_world),
            Vector3::from(self.center),
        )
    }
}

/// A calibration's stated 1-sigma uncertainty (see `formats::calibration`):
/// all zero when not stated (a recording made before v2).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.CalibrationUncertainty.v1")]
#[repr(C)]
pub struct CalibrationUncertainty {
    /// 1 if stated.
    pub stated: u32,
    /// Valid entries in `joint_offsets_deg`.
    pub dof: u32,
    /// Training samples the outlier test set aside (not in `samples`).
    pub rejected_samples: u32,
    /// Explicit padding.
    pub reserved: u32,
    /// The fit's residual standard deviation per pixel coordinate, px.
    pub residual_px: f64,
    /// RMS angle between the true and the estimated normal, deg (0 without
    /// a plane).
    pub plane_angle_deg: f64,
    /// The plane offset, mm (0 without a plane).
    pub plane_distance_mm: f64,
    /// Each encoder offset, deg; [`UNDETERMINED`] where the samples do not
    /// determine it.
    pub joint_offsets_deg: [f64; MAX_JOINTS],
    /// RMS error of each mirror camera's centre, mm, left then right.
    pub mirror_camera_centers_mm: [f64; 2],
    /// RMS rotation error of each mirror camera, deg, left then right.
    pub mirror_camera_angles_deg: [f64; 2],
}

/// A 1-sigma value for a parameter the samples do not determine (no NaN
/// on the wire: messages are compared bit for bit).
pub const UNDETERMINED: f64 = -1.0;

/// Whether a calibration still holds: the world it was made in may have
/// changed under it (a moved mirror, a knocked camera). All zero in a
/// recording made before v3: epoch 0, not stated.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.CalibrationEpoch.v1")]
#[repr(C)]
pub struct CalibrationEpoch {
    /// Which calibration of an unchanged world this is, from 1; a change
    /// found starts the next once it is calibrated again. 0: not stated.
    pub epoch: u32,
    /// [`EpochState`].
    pub state: u32,
    /// [`Moved`]: what changed (for a drifted calibration, and for an epoch
    /// after the first, what ended the one before).
    pub moved: u32,
    /// The camera that moved (0 left, 1 right), for [`Moved::Camera`].
    pub camera: u32,
    /// The pose at which the epoch began (0 for the first); for a drifted
    /// calibration, the pose at which the change began.
    pub began_at_pose: u64,
    /// For a drifted calibration, the pose at which the change was found.
    pub found_at_pose: u64,
}

/// The state of a calibration ([`CalibrationEpoch::state`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum EpochState {
    /// It holds, as far as the samples show.
    Calibrated = 0,
    /// The world changed under it: what it says is no longer true; the
    /// stage calibrates again from the samples that follow.
    Drifted = 1,
    /// The world changed and cannot be calibrated again from what the
    /// plan gives (a camera moved, and no direct view came to find it).
    Stopped = 2,
}

/// What changed under a calibration ([`CalibrationEpoch::moved`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum Moved {
    /// Nothing (the first epoch).
    Nothing = 0,
    /// The mirror.
    Mirror = 1,
    /// One head camera ([`CalibrationEpoch::camera`]).
    Camera = 2,
    /// Both cameras as one: the head (or the arm's base).
    Head = 3,
}

impl CalibrationEpoch {
    /// The state, if valid.
    pub fn state(&self) -> Option<EpochState> {
        [
            EpochState::Calibrated,
            EpochState::Drifted,
            EpochState::Stopped,
        ]
        .into_iter()
        .find(|s| *s as u32 == self.state)
    }

    /// What moved, if valid.
    pub fn moved(&self) -> Option<Moved> {
        [Moved::Nothing, Moved::Mirror, Moved::Camera, Moved::Head]
            .into_iter()
            .find(|m| *m as u32 == self.moved)
    }
}

/// A calibration of the mirror cameras. v2 appended `uncertainty` to v1,
/// v3 `epoch` to v2; a recording of an earlier version reads with them
/// zero (not stated).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.Calibration.v3")]
#[repr(C)]
pub struct CalibrationMsg {
    /// Stamp of the newest sample used, ns.
    pub stamp_ns: i64,
    /// Number of calibrations published so far (1 for the first).
    pub revision: u64,
    /// 0 paper, 1 joint, 2 joint+kinematics.
    pub method: u32,
    /// Training samples used.
    pub samples: u32,
    /// 1 if `plane` is set.
    pub has_plane: u32,
    /// Valid entries in `joint_offsets`.
    pub dof: u32,
    /// Plane normal (towards the robot) and offset `d`.
    pub plane: [f64; 4],
    /// Mirror cameras, left then right.
    pub cameras: [CameraPose; 2],
    /// Estimated encoder offsets, rad.
    pub joint_offsets: [f64; MAX_JOINTS],
    /// RMS training reprojection error, px.
    pub train_rms_px: f64,
    /// What it is known to.
    pub uncertainty: CalibrationUncertainty,
    /// Whether it still holds, and which epoch it belongs to.
    pub epoch: CalibrationEpoch,
}

/// A test sample's prediction through the current calibration.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.Prediction.v1")]
#[repr(C)]
pub struct Prediction {
    /// Pose id.
    pub pose: u64,
    /// Stamp of the sample, ns.
    pub stamp_ns: i64,
    /// Calibration revision used.
    pub revision: u64,
    /// [`Role`].
    pub role: u32,
    /// Explicit padding.
    pub reserved: u32,
    /// The model's `J` (with estimated offsets), mm.
    pub model_point: [f64; 3],
    /// The detection reconstructed through the (mirror) cameras, mm.
    pub reconstructed: [f64; 3],
    /// `J` projected into left and right, px.
    pub predicted_pixels: [[f64; 2]; 2],
    /// 3D error, mm.
    pub error_mm: f64,
    /// Mean 2D error over both cameras, px.
    pub error_px: f64,
}

/// A marker other than the arm's, located through the mirror. v2 appended
/// the covariance to v1; a v1 recording reads with it zero (not stated).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.LocatedObject.v2")]
#[repr(C)]
pub struct LocatedObject {
    /// Stamp of the detection, ns.
    pub stamp_ns: i64,
    /// Calibration revision used.
    pub revision: u64,
    /// Marker id.
    pub id: u32,
    /// Explicit padding.
    pub reserved: u32,
    /// Position in the world (robot) frame, mm.
    pub position: [f64; 3],
    /// Predicted covariance of `position` (calibration and detection
    /// noise), mm^2: xx, xy, xz, yy, yz, zz. Zero when not stated.
    pub covariance_mm2: [f64; 6],
}

impl LocatedObject {
    /// The predicted 1-sigma position error, mm: the RMS distance between
    /// the true and the located point, `sqrt(trace)`. 0 when not stated.
    pub fn sigma_mm(&self) -> f64 {
        let c = &self.covariance_mm2;
        (c[0] + c[3] + c[5]).max(0.0).sqrt()
    }

    /// The covariance as a matrix, mm^2.
    pub fn covariance(&self) -> Matrix3<f64> {
        let c = &self.covariance_mm2;
        Matrix3::new(c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5])
    }
}

/// The arm driver's raw joint positions (its encoders), as it reads them.
/// Published by the arm driver, whatever drives the arm; a robot's own
/// driver publishes this (see `python/mirror_driver`).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.JointPositions.v1")]
#[repr(C)]
pub struct JointPositions {
    /// Message sequence number.
    pub seq: u64,
    /// Time of the reading, ns (CLOCK_MONOTONIC of the driver's host).
    pub stamp_ns: i64,
    /// Valid entries in `q`.
    pub dof: u32,
    /// Explicit padding.
    pub reserved: u32,
    /// Joint positions, base to tip: rad (revolute) or mm (prismatic).
    pub q: [f64; MAX_JOINTS],
}

impl JointPositions {
    /// The valid joint positions.
    pub fn joints(&self) -> &[f64] {
        &self.q[..(self.dof as usize).min(MAX_JOINTS)]
    }

    /// What makes this message unusable for an arm of `dof` joints, if anything.
    pub fn fault(&self, dof: usize) -> Option<String> {
        if self.dof as usize != dof {
            return Some(format!("{} joints, the arm has {dof}", self.dof));
        }
        if !self.joints().iter().all(|v| v.is_finite()) {
            return Some("non-finite joint position".into());
        }
        None
    }
}

/// A pose the arm is to move to, sent to the arm driver by
/// `kinematics_proc`, which owns the plan. A driver moves to the latest
/// goal it received; the same goal may be sent again (same `pose`).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Pod, Zeroable)]
#[type_name("mirror.PoseGoal.v1")]
#[repr(C)]
pub struct PoseGoal {
    /// Message sequence number.
    pub seq: u64,
    /// When it was sent, ns.
    pub stamp_ns: i64,
    /// Pose id of the plan.
    pub pose: u64,
    /// [`Role`] of the pose.
    pub role: u32,
    /// Valid entries in `q`.
    pub dof: u32,
    /// [`PoseGoal::FINISHED`] once the plan is over (then `q` is unused).
    pub flags: u32,
    /// Explicit padding.
    pub reserved: u32,
    /// Target joint positions, base to tip: rad or mm.
    pub q: [f64; MAX_JOINTS],
}

impl PoseGoal {
    /// Flag: the plan is over; the driver may stop.
    pub const FINISHED: u32 = 1;

    /// The valid targets.
    pub fn joints(&self) -> &[f64] {
        &self.q[..(self.dof as usize).min(MAX_JOINTS)]
    }

    /// Whether this goal ends the plan.
    pub fn finished(&self) -> bool {
        self.flags & Self::FINISHED != 0
    }

    /// What makes this goal unusable for an arm of `dof` joints, if anything.
    pub fn fault(&self, dof: usize) -> Option<String> {
        if self.finished() {
            return None;
        }
        if self.dof as usize != dof {
            return Some(format!("{} joints, the arm has {dof}", self.dof));
        }
        if !self.joints().iter().all(|v| v.is_finite()) {
            return Some("non-finite target".into());
        }
        if Role::try_from(self.role).is_err() {
            return Some(format!("role {} unknown", self.role));
        }
        None
    }
}

// No implicit padding: each size equals the sum of its fields.
const _: () = {
    assert!(size_of::<FrameHeader>() == 8 * 3 + 4 * 4);
    assert!(size_of::<Marker>() == 4 + 4 + 8 * 8 + 2 * 8);
    assert!(size_of::<CameraMarkers>() == 8 + MAX_MARKERS * size_of::<Marker>());
    assert!(size_of::<StereoDetections>() == 24 + 2 * size_of::<CameraMarkers>());
    assert!(size_of::<JointState>() == 8 * 3 + 4 * 4 + 8 * MAX_JOINTS + 24);
    assert!(size_of::<MirrorSample>() == 16 + 8 + 8 * MAX_JOINTS + 24 + 32 + 24);
    assert!(size_of::<CameraPose>() == 12 * 8);
    assert!(size_of::<CalibrationUncertainty>() == 16 + 3 * 8 + 8 * MAX_JOINTS + 4 * 8);
    assert!(
        size_of::<CalibrationMsg>()
            == 16
                + 16
                + 32
                + 2 * 96
                + 8 * MAX_JOINTS
                + 8
                + size_of::<CalibrationUncertainty>()
                + size_of::<CalibrationEpoch>()
    );
    assert!(size_of::<CalibrationEpoch>() == 16 + 16);
    assert!(size_of::<Prediction>() == 24 + 8 + 24 + 24 + 32 + 16);
    assert!(size_of::<LocatedObject>() == 16 + 8 + 24 + 48);
    assert!(size_of::<JointPositions>() == 8 * 2 + 4 * 2 + 8 * MAX_JOINTS);
    assert!(size_of::<PoseGoal>() == 8 * 3 + 4 * 4 + 8 * MAX_JOINTS);
};

/// Moving a message's times onto another host's clock: what the bridge
/// between hosts does to every message it receives.
pub trait ShiftClock {
    /// Adds `by_ns` to every time the message holds. A time of 0 means
    /// "not known" and stays 0; the sum saturates (bytes from a network may
    /// hold anything).
    fn shift_clock(&mut self, by_ns: i64);
}

fn shift(t: &mut i64, by_ns: i64) {
    if *t != 0 {
        *t = t.saturating_add(by_ns);
    }
}

impl ShiftClock for FrameHeader {
    fn shift_clock(&mut self, by_ns: i64) {
        shift(&mut self.stamp_ns, by_ns);
        shift(&mut self.published_ns, by_ns);
    }
}

impl ShiftClock for StereoDetections {
    fn shift_clock(&mut self, by_ns: i64) {
        shift(&mut self.stamp_ns, by_ns);
        shift(&mut self.frame_published_ns, by_ns);
    }
}

/// Messages whose one time is `stamp_ns`.
macro_rules! shift_stamp {
    ($($t:ty),*) => {$(
        impl ShiftClock for $t {
            fn shift_clock(&mut self, by_ns: i64) {
                shift(&mut self.stamp_ns, by_ns);
            }
        }
    )*};
}

shift_stamp!(
    JointState,
    MirrorSample,
    CalibrationMsg,
    Prediction,
    LocatedObject,
    JointPositions,
    PoseGoal
);
