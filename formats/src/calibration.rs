//! The calibration file (JSON). `cameras` are the mirror-perspective cameras
//! (`P = K [R | -R C]` with the real cameras' intrinsics); `plane` is absent
//! for a method that has none; `joint_offsets` are added to the joint values
//! (`theta = q + theta_offset + joint_offset`), one per entry of `q` in the
//! order of `joint_names` (the arm's joints from base to tip). Readers ignore
//! unknown keys.
//!
//! ```json
//! {
//!   "method": "joint+kinematics",
//!   "plane": { "normal": [0.0, 0.0, -1.0], "distance": 480.0 },
//!   "cameras": [
//!     { "name": "left",  "camera_from_world": [1, 0, 0, 0, 1, 0, 0, 0, 1], "center": [-30, 0, 960] },
//!     { "name": "right", "camera_from_world": [1, 0, 0, 0, 1, 0, 0, 0, 1], "center": [30, 0, 960] }
//!   ],
//!   "joint_offsets": [0.0, 0.0, 0.0, 0.0],
//!   "joint_names": ["joint1", "joint2", "joint3", "joint4"],
//!   "train_rms_px": 0.6,
//!   "samples": 20,
//!   "uncertainty": {
//!     "residual_px": 0.5,
//!     "plane_angle_deg": 0.004,
//!     "plane_distance_mm": 0.03,
//!     "joint_offsets_deg": [0.002, 0.003, 0.004, 0.005],
//!     "mirror_camera_centers_mm": [0.06, 0.06],
//!     "mirror_camera_angles_deg": [0.004, 0.004]
//!   }
//! }
//! ```
//!
//! `uncertainty` holds 1-sigma values from the fit's covariance (see
//! `docs/methods.md`): for a vector quantity (a normal, a centre) the RMS of
//! its error, `sqrt(E[|error|^2])`. A parameter the samples do not
//! determine has `null` and is named in `undetermined`. Files written
//! before it existed have none. `rejected_samples` (absent when empty)
//! lists the samples set aside as not fitting the others:
//! `[{ "pose": 12, "residual_px": 48.3 }]`.

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use geometry::{Camera, Plane, Rig};
use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};

use crate::{
    FormatError, check_finite, check_rotation, mat3, mat3_row_major, read_text, write_text,
};

/// A mirror plane `n . X + d = 0`, normal towards the robot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlaneEntry {
    /// Unit normal.
    pub normal: [f64; 3],
    /// `d`.
    pub distance: f64,
}

/// One mirror-perspective camera's pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraPose {
    /// Name of the real camera it mirrors.
    pub name: String,
    /// Row-major `R` (camera from world).
    pub camera_from_world: [f64; 9],
    /// Centre in world, mm.
    pub center: [f64; 3],
}

/// A head camera found again after it was knocked: its pose now, which
/// replaces the rig's (`head_cameras` of a calibration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeadCameraEntry {
    /// The rig's name of the camera.
    pub name: String,
    /// Row-major `R` (camera from world), as found.
    pub camera_from_world: [f64; 9],
    /// Centre in world, mm (kept: only the turn is found).
    pub center: [f64; 3],
    /// How far it turned from the rig's pose, deg.
    pub turn_deg: f64,
    /// The 1-sigma of its orientation about its own x (tilt), y (pan) and
    /// z (optical) axes, deg.
    pub sigma_deg: [f64; 3],
    /// Direct views it was found from.
    pub views: usize,
    /// The pose at which it moved.
    pub moved_at_pose: u64,
}

/// A calibration's 1-sigma uncertainty (see the module's documentation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UncertaintyEntry {
    /// The fit's residual standard deviation per pixel coordinate, px.
    pub residual_px: f64,
    /// RMS angle between the true and the estimated mirror normal, deg.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane_angle_deg: Option<f64>,
    /// The plane offset `d`, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane_distance_mm: Option<f64>,
    /// Each encoder offset, deg (mm for a prismatic joint; `null`: not
    /// determined).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_offsets_deg: Option<Vec<Option<f64>>>,
    /// RMS error of each mirror camera's centre, mm, left then right.
    pub mirror_camera_centers_mm: [f64; 2],
    /// RMS rotation error of each mirror camera, deg, left then right.
    pub mirror_camera_angles_deg: [f64; 2],
    /// What the samples do not determine.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub undetermined: Vec<String>,
    /// Each placement's plane, when calibrated across more than one (the
    /// first is also `plane_angle_deg` and `plane_distance_mm`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub placements: Vec<PlaneSigmaEntry>,
    /// RMS distance between the true and the estimated base origin, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base_translation_mm: Option<f64>,
    /// RMS rotation angle between the true and the estimated base, deg.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base_rotation_deg: Option<f64>,
    /// RMS distance between the true and the estimated tool point, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool_mm: Option<f64>,
}

/// One placement's plane sigmas.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlaneSigmaEntry {
    /// RMS angle between the true and the estimated normal, deg.
    pub plane_angle_deg: Option<f64>,
    /// The plane offset `d`, mm.
    pub plane_distance_mm: Option<f64>,
}

/// One mirror placement of a calibration across several.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlacementEntry {
    /// Its mirror plane.
    pub plane: PlaneEntry,
    /// Its mirror-perspective cameras, left then right.
    pub cameras: Vec<CameraPose>,
    /// Its mirror samples used.
    pub samples: usize,
}

/// Whether a calibration's model explains its samples to the expected noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FitVerdict {
    /// The residuals are what the noise explains.
    Good,
    /// They are larger: the figures are not to be trusted.
    Poor,
}

impl FitVerdict {
    /// Its name in files: `good` or `poor`.
    pub fn as_str(self) -> &'static str {
        match self {
            FitVerdict::Good => "good",
            FitVerdict::Poor => "poor",
        }
    }
}

/// A sample the calibration set aside as not fitting the others.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RejectedEntry {
    /// Its pose id.
    pub pose: u64,
    /// Its RMS reprojection error over both cameras under the calibration, px.
    pub residual_px: f64,
    /// The placement (index of the samples file) it came from, when
    /// calibrated across more than one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub placement: Option<usize>,
}

/// A calibration as stored on disk.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationFile {
    /// `paper`, `joint` or `joint+kinematics`.
    pub method: String,
    /// The mirror plane, for methods that estimate one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane: Option<PlaneEntry>,
    /// Mirror-perspective cameras, left then right.
    pub cameras: Vec<CameraPose>,
    /// Estimated encoder offsets, rad.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_offsets: Option<Vec<f64>>,
    /// The arm's joints, base to tip: what `joint_offsets` and the samples'
    /// `q` columns follow.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_names: Option<Vec<String>>,
    /// RMS reprojection error on the training samples, px.
    pub train_rms_px: f64,
    /// Number of training samples used.
    pub samples: usize,
    /// What the solved values are known to.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<UncertaintyEntry>,
    /// Samples set aside as not fitting the others.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rejected_samples: Vec<RejectedEntry>,
    /// Whether the samples kept fit the model to the expected noise;
    /// absent when not judged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit: Option<FitVerdict>,
    /// For a poor fit, its likely cause.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit_cause: Option<String>,
    /// Direct-view samples used as constraints.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub direct_samples: usize,
    /// Every placement, when calibrated across more than one; `plane` and
    /// `cameras` are then the first's.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub placements: Vec<PlacementEntry>,
    /// The arm's base placement, estimated: row-major 4x4, mm, as the
    /// rig's `world_from_base`, which it replaces.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub world_from_base: Option<[f64; 16]>,
    /// The marker centre in the last link's frame, estimated, mm, as the
    /// rig's `tool`, which it replaces.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool: Option<[f64; 3]>,
    /// Head cameras found again after they moved (the live stage's drift
    /// watch): each replaces the rig's camera of its name.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub head_cameras: Vec<HeadCameraEntry>,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// The file form of a plane.
fn plane_entry(p: &Plane) -> PlaneEntry {
    PlaneEntry {
        normal: p.normal.into_inner().into(),
        distance: p.distance,
    }
}

/// The file form of a pair of mirror cameras.
fn camera_poses(names: &[String; 2], cameras: &[Camera; 2]) -> Vec<CameraPose> {
    cameras
        .iter()
        .zip(names)
        .map(|(c, n)| CameraPose {
            name: n.clone(),
            camera_from_world: mat3_row_major(&c.camera_from_world),
            center: c.center.into(),
        })
        .collect()
}

impl CalibrationFile {
    /// Builds the file form from geometry types.
    pub fn new(
        method: &str,
        plane: Option<&Plane>,
        names: &[String; 2],
        cameras: &[Camera; 2],
        joint_offsets: Option<&[f64]>,
        train_rms_px: f64,
        samples: usize,
    ) -> Self {
        Self {
            method: method.to_string(),
            plane: plane.map(plane_entry),
            cameras: camera_poses(names, cameras),
            joint_offsets: joint_offsets.map(<[f64]>::to_vec),
            joint_names: None,
            train_rms_px,
            samples,
            uncertainty: None,
            rejected_samples: Vec::new(),
            fit: None,
            fit_cause: None,
            direct_samples: 0,
            placements: Vec::new(),
            world_from_base: None,
            tool: None,
            head_cameras: Vec::new(),
        }
    }

    /// With every placement's plane, cameras and sample count, when there
    /// is more than one (one placement is the top-level plane alone).
    pub fn with_placements(
        mut self,
        names: &[String; 2],
        placements: &[(Plane, [Camera; 2], usize)],
    ) -> Self {
        self.placements = if placements.len() > 1 {
            placements
                .iter()
                .map(|(plane, cameras, samples)| PlacementEntry {
                    plane: plane_entry(plane),
                    cameras: camera_poses(names, cameras),
                    samples: *samples,
                })
                .collect()
        } else {
            Vec::new()
        };
        self
    }

    /// With the arm's estimated base and tool, and the direct samples used.
    pub fn with_arm_estimate(
        mut self,
        world_from_base: Option<&Isometry3<f64>>,
        tool: Option<&Vector3<f64>>,
        direct_samples: usize,
    ) -> Self {
        self.world_from_base = world_from_base.map(crate::pose_row_major);
        self.tool = tool.map(|t| (*t).into());
        self.direct_samples = direct_samples;
        self
    }

    /// With the head cameras found again after they moved.
    pub fn with_head_cameras(mut self, cameras: Vec<HeadCameraEntry>) -> Self {
        self.head_cameras = cameras;
        self
    }

    /// The rig with the calibration's estimated base and tool in its arm
    /// and its head cameras found again (unchanged where the calibration
    /// found none of them); `path` names the calibration in errors.
    pub fn corrected_rig(&self, path: &Path, rig: &Rig) -> Result<Rig, FormatError> {
        let mut rig = rig.clone();
        for (i, found) in self.head_cameras.iter().enumerate() {
            let key = format!("head_cameras[{i}]");
            let k = rig
                .names
                .iter()
                .position(|n| *n == found.name)
                .ok_or_else(|| {
                    FormatError::at_key(
                        path,
                        &key,
                        format!(
                            "names camera `{}`, which the rig does not have ({} and {})",
                            found.name, rig.names[0], rig.names[1]
                        ),
                    )
                })?;
            let r = mat3(&found.camera_from_world);
            check_rotation(path, &format!("{key}.camera_from_world"), &r, false)?;
            check_finite(path, &format!("{key}.center"), &found.center)?;
            rig.cameras[k].camera_from_world = r;
            rig.cameras[k].center = Vector3::from(found.center);
        }
        if let Some(arm) = rig.arm.as_mut() {
            if let Some(m) = &self.world_from_base {
                arm.world_from_base = crate::parse_pose(path, "world_from_base", m)?;
            }
            if let Some(t) = &self.tool {
                arm.tool = Vector3::from(*t);
            }
        } else if self.world_from_base.is_some() || self.tool.is_some() {
            return Err(FormatError::at_key(
                path,
                "world_from_base",
                "the calibration estimated the arm's base or tool, but the rig has no [arm]",
            ));
        }
        Ok(rig)
    }

    /// Placement `index`'s mirror cameras (0 is the top-level `cameras`),
    /// with the intrinsics of the rig's real cameras; `None` past the last.
    pub fn placement_cameras(&self, rig: &Rig, index: usize) -> Option<[Camera; 2]> {
        if index == 0 {
            return Some(self.mirror_cameras(rig));
        }
        let entry = self.placements.get(index)?;
        Some(std::array::from_fn(|k| {
            Camera::new(
                rig.cameras[k].intrinsics,
                mat3(&entry.cameras[k].camera_from_world),
                Vector3::from(entry.cameras[k].center),
            )
        }))
    }

    /// With the samples it set aside.
    pub fn with_rejected(mut self, rejected: Vec<RejectedEntry>) -> Self {
        self.rejected_samples = rejected;
        self
    }

    /// With the verdict on its fit and, for a poor one, the likely cause.
    pub fn with_fit(mut self, fit: Option<(FitVerdict, Option<String>)>) -> Self {
        (self.fit, self.fit_cause) = match fit {
            Some((verdict, cause)) => (Some(verdict), cause),
            None => (None, None),
        };
        self
    }

    /// With its uncertainty.
    pub fn with_uncertainty(mut self, uncertainty: UncertaintyEntry) -> Self {
        self.uncertainty = Some(uncertainty);
        self
    }

    /// With the names of the rig's arm joints, if it has an arm.
    pub fn with_joint_names(mut self, rig: &Rig) -> Self {
        self.joint_names = rig.arm.as_ref().map(geometry::Arm::joint_names);
        self
    }

    /// Fails unless the calibration (read from `path`) was made for the
    /// rig's arm: the same joint names, one offset per joint.
    pub fn check_arm(&self, path: &Path, rig: &Rig) -> Result<(), FormatError> {
        let Some(arm) = &rig.arm else { return Ok(()) };
        if let Some(names) = &self.joint_names
            && *names != arm.joint_names()
        {
            return Err(FormatError::at_key(
                path,
                "joint_names",
                format!(
                    "{names:?} are not the rig's arm joints {:?}",
                    arm.joint_names()
                ),
            ));
        }
        if let Some(offsets) = &self.joint_offsets
            && offsets.len() != arm.dof()
        {
            return Err(FormatError::at_key(
                path,
                "joint_offsets",
                format!(
                    "{} offsets but the rig's arm has {} joints",
                    offsets.len(),
                    arm.dof()
                ),
            ));
        }
        Ok(())
    }

    /// The mirror cameras, with the intrinsics of the rig's real cameras.
    pub fn mirror_cameras(&self, rig: &Rig) -> [Camera; 2] {
        let pose = |k: usize| {
            Camera::new(
                rig.cameras[k].intrinsics,
                mat3(&self.cameras[k].camera_from_world),
                Vector3::from(self.cameras[k].center),
            )
        };
        [pose(0), pose(1)]
    }

    /// The mirror plane, if any.
    pub fn plane(&self) -> Option<Plane> {
        self.plane
            .as_ref()
            .and_then(|p| Plane::new(Vector3::from(p.normal), p.distance).ok())
    }

    /// Joint offsets, or none when absent or all zero.
    pub fn nonzero_joint_offsets(&self) -> Option<&[f64]> {
        self.joint_offsets
            .as_deref()
            .filter(|o| o.iter().any(|v| *v != 0.0))
    }

    /// Renders as pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a calibration always serialises") + "\n"
    }
}

/// Reads and validates a calibration file.
pub fn read(path: impl AsRef<Path>) -> Result<CalibrationFile, FormatError> {
    let path = path.as_ref();
    parse(path, &read_text(path)?)
}

/// Parses calibration JSON; `path` is only used in error messages.
pub fn parse(path: &Path, text: &str) -> Result<CalibrationFile, FormatError> {
    let cal: CalibrationFile = serde_json::from_str(text).map_err(|e| {
        FormatError::new(
            path,
            Some(format!("line {}", e.line())),
            strip_position(&e.to_string()),
        )
    })?;
    if cal.cameras.len() != 2 {
        return Err(FormatError::at_key(
            path,
            "cameras",
            format!("expected 2 cameras, found {}", cal.cameras.len()),
        ));
    }
    for (k, c) in cal.cameras.iter().enumerate() {
        check_rotation(
            path,
            &format!("cameras[{k}].camera_from_world"),
            &mat3(&c.camera_from_world),
            true,
        )?;
        check_finite(path, &format!("cameras[{k}].center"), &c.center)?;
    }
    if let Some(p) = &cal.plane {
        check_finite(
            path,
            "plane",
            &[p.normal[0], p.normal[1], p.normal[2], p.distance],
        )?;
        if (Vector3::from(p.normal).norm() - 1.0).abs() > 1e-6 {
            return Err(FormatError::at_key(
                path,
                "plane.normal",
                "is not a unit vector",
            ));
        }
    }
    for (i, p) in cal.placements.iter().enumerate() {
        if p.cameras.len() != 2 {
            return Err(FormatError::at_key(
                path,
                format!("placements[{i}].cameras"),
                format!("expected 2 cameras, found {}", p.cameras.len()),
            ));
        }
        for (k, c) in p.cameras.iter().enumerate() {
            let key = format!("placements[{i}].cameras[{k}]");
            check_rotation(
                path,
                &format!("{key}.camera_from_world"),
                &mat3(&c.camera_from_world),
                true,
            )?;
            check_finite(path, &format!("{key}.center"), &c.center)?;
        }
        check_finite(
            path,
            &format!("placements[{i}].plane"),
            &[
                p.plane.normal[0],
                p.plane.normal[1],
                p.plane.normal[2],
                p.plane.distance,
            ],
        )?;
    }
    if let Some(m) = &cal.world_from_base {
        crate::parse_pose(path, "world_from_base", m)?;
    }
    if let Some(t) = &cal.tool {
        check_finite(path, "tool", t)?;
    }
    if let Some(o) = &cal.joint_offsets {
        check_finite(path, "joint_offsets", o)?;
        if let Some(names) = &cal.joint_names
            && names.len() != o.len()
        {
            return Err(FormatError::at_key(
                path,
                "joint_names",
                format!("{} names for {} joint offsets", names.len(), o.len()),
            ));
        }
    }
    Ok(cal)
}

/// serde_json appends " at line L column C"; the location is reported separately.
fn strip_position(message: &str) -> String {
    match message.rfind(" at line ") {
        Some(i) => message[..i].to_string(),
        None => message.to_string(),
    }
}

/// Writes a calibration file.
pub fn write(path: impl AsRef<Path>, cal: &CalibrationFile) -> Result<(), FormatError> {
    write_text(path.as_ref(), &cal.to_json())
}

/// A calibration method. The discriminants are the wire and recording
/// values (`CalibrationMsg::method`): never reorder them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[repr(u32)]
pub enum Method {
    /// The paper's per-camera method.
    #[serde(rename = "paper")]
    Paper = 0,
    /// A shared mirror plane.
    #[serde(rename = "joint")]
    Joint = 1,
    /// A shared mirror plane and per-joint encoder offsets.
    #[serde(rename = "joint+kinematics")]
    JointKinematics = 2,
}

geometry::try_from_u32!(Method);

impl Method {
    /// All methods, in the order reports list them.
    pub const ALL: [Method; 3] = [Method::Paper, Method::Joint, Method::JointKinematics];

    /// The method's name in files and on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Method::Paper => "paper",
            Method::Joint => "joint",
            Method::JointKinematics => "joint+kinematics",
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A method name that is none of [`Method::ALL`]'s.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "unknown method `{0}` (expected {known})",
    known = Method::ALL.map(Method::as_str).join(", ")
)]
pub struct UnknownMethod(pub String);

impl FromStr for Method {
    type Err = UnknownMethod;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Method::ALL
            .into_iter()
            .find(|m| m.as_str() == s)
            .ok_or_else(|| UnknownMethod(s.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::sim::nico_scene;

    #[test]
    fn round_trips_and_reports_bad_keys() {
        let scene = nico_scene();
        let plane = scene.mirrors[0].plane;
        let cams = scene.rig.cameras.map(|c| plane.mirror_camera(&c));
        let cal = CalibrationFile::new(
            "joint",
            Some(&plane),
            &scene.rig.names,
            &cams,
            Some(&[0.0; 4]),
            0.5,
            10,
        );
        let p = Path::new("c.json");
        let back = parse(p, &cal.to_json()).unwrap();
        assert_eq!(back, cal);
        assert_eq!(back.mirror_cameras(&scene.rig), cams);
        let e = parse(p, "{\"method\": \"joint\"}").unwrap_err().to_string();
        assert_eq!(e, "c.json: line 1: missing field `cameras`");
        let mut bad = cal.clone();
        bad.cameras[1].camera_from_world[0] = 3.0;
        let e = parse(p, &bad.to_json()).unwrap_err().to_string();
        assert!(
            e.starts_with("c.json: key cameras[1].camera_from_world: is not a rotation"),
            "{e}"
        );
    }

    #[test]
    fn a_calibration_for_other_joints_is_refused_naming_the_key() {
        let scene = nico_scene();
        let cams = scene.rig.cameras;
        let p = Path::new("c.json");
        let cal = CalibrationFile::new(
            "joint",
            None,
            &scene.rig.names,
            &cams,
            Some(&[0.0; 4]),
            0.5,
            10,
        )
        .with_joint_names(&scene.rig);
        assert_eq!(cal.check_arm(p, &scene.rig), Ok(()));
        let mut renamed = cal.clone();
        renamed.joint_names = Some(vec!["a".into(), "b".into(), "c".into(), "d".into()]);
        let e = renamed.check_arm(p, &scene.rig).unwrap_err().to_string();
        assert!(e.starts_with("c.json: key joint_names: [\"a\""), "{e}");
        let mut short = cal.clone();
        short.joint_names = None;
        short.joint_offsets = Some(vec![0.0; 3]);
        let e = short.check_arm(p, &scene.rig).unwrap_err().to_string();
        assert_eq!(
            e,
            "c.json: key joint_offsets: 3 offsets but the rig's arm has 4 joints"
        );
    }
}
