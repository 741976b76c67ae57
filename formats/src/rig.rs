//! The rig file (TOML): both cameras and, optionally, the arm's DH model.
//!
//! A camera's intrinsics are given inline (distortion as `k1`, `k2` or as
//! `dist`, 4, 5 or 8 coefficients in OpenCV's order) or by a calibration
//! file ([`crate::camera_file`]); its pose is always in the rig.
//!
//! ```toml
//! pixel_sigma = 0.2               # optional: the detections' noise, px (1 sigma per coordinate)
//!
//! [[camera]]                      # first = left, second = right
//! name = "left"
//! width = 640
//! height = 480
//! fx = 550.0
//! fy = 550.0
//! skew = 0.0
//! cx = 320.0
//! cy = 240.0
//! dist = [-0.25, 0.08, 0.001, -0.0005, 0.01]  # OpenCV's order: k1, k2, p1, p2, k3 [, k4, k5, k6]
//! camera_from_world = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]  # row-major R
//! center = [-30.0, 0.0, 0.0]      # C in world, mm
//!
//! [[camera]]
//! name = "right"
//! calibration = "right.yaml"      # ROS camera_info or OpenCV YAML, relative to this file
//! camera_from_world = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
//! center = [30.0, 0.0, 0.0]
//!
//! [arm]                           # a DH table, or urdf = "robot.urdf" with base_link and tip_link
//! world_from_base = [1.0, 0.0, 0.0, 0.0,  0.0, 1.0, 0.0, 0.0,  0.0, 0.0, 1.0, 0.0,  0.0, 0.0, 0.0, 1.0]
//! tool = [0.0, 0.0, 0.0]          # marker centre in the last link's frame
//! joints = [
//!   { a = 0.0, alpha = 1.5707963, d = 0.0, theta_offset = 0.0, min = -1.0, max = 1.0 },
//! ]
//! ```

use std::path::Path;

use geometry::{Arm, ArmModel, Camera, DhJoint, Distortion, Intrinsics, Rig};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::{
    FormatError, check_finite, check_rotation, mat3, mat3_row_major, read_text, write_text,
};

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigFile {
    /// The detections' noise, px per coordinate (1 sigma).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pixel_sigma: Option<f64>,
    camera: Vec<CameraEntry>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    arm: Option<ArmEntry>,
}

#[derive(Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraEntry {
    name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    calibration: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    width: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    height: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fy: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    skew: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cy: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    k1: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    k2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    dist: Option<Vec<f64>>,
    camera_from_world: [f64; 9],
    center: [f64; 3],
}

impl CameraEntry {
    /// The intrinsics: from the calibration file (resolved against the
    /// rig's folder) or from the inline keys.
    fn intrinsics(&self, path: &Path, i: usize) -> Result<Intrinsics, FormatError> {
        let key = |k: &str| format!("camera[{i}].{k}");
        let inline = [
            ("width", self.width.is_some()),
            ("height", self.height.is_some()),
            ("fx", self.fx.is_some()),
            ("fy", self.fy.is_some()),
            ("skew", self.skew.is_some()),
            ("cx", self.cx.is_some()),
            ("cy", self.cy.is_some()),
            ("k1", self.k1.is_some()),
            ("k2", self.k2.is_some()),
            ("dist", self.dist.is_some()),
        ];
        if let Some(file) = &self.calibration {
            if let Some((k, _)) = inline.iter().find(|(_, given)| *given) {
                return Err(FormatError::at_key(
                    path,
                    key(k),
                    "given beside calibration; the calibration file sets the intrinsics",
                ));
            }
            let file = path.parent().unwrap_or(Path::new("")).join(file);
            return crate::camera_file::read(&file)
                .map(|(k, _)| k)
                .map_err(|e| FormatError::at_key(path, key("calibration"), e.to_string()));
        }
        let need = |k: &str, v: Option<f64>| {
            v.ok_or_else(|| {
                FormatError::at_key(
                    path,
                    key(k),
                    "missing: give the intrinsics or calibration = \"FILE\"",
                )
            })
        };
        let size = |k: &str, v: Option<u32>| need(k, v.map(f64::from)).map(|_| v.unwrap_or(0));
        let (width, height) = (size("width", self.width)?, size("height", self.height)?);
        let (fx, fy, cx, cy) = (
            need("fx", self.fx)?,
            need("fy", self.fy)?,
            need("cx", self.cx)?,
            need("cy", self.cy)?,
        );
        let skew = self.skew.unwrap_or(0.0);
        let dist = match &self.dist {
            Some(_) if self.k1.is_some() || self.k2.is_some() => {
                return Err(FormatError::at_key(
                    path,
                    key("dist"),
                    "given beside k1/k2; give one or the other",
                ));
            }
            Some(d) => Distortion::from_opencv(d)
                .map_err(|e| FormatError::at_key(path, key("dist"), e.to_string()))?,
            None => Distortion::radial(self.k1.unwrap_or(0.0), self.k2.unwrap_or(0.0)),
        };
        check_finite(path, &key("intrinsics"), &[fx, fy, skew, cx, cy])?;
        check_finite(path, &key("dist"), &dist.to_opencv())?;
        if width == 0 || height == 0 {
            return Err(FormatError::at_key(
                path,
                key("width"),
                "image size must be positive",
            ));
        }
        if !(fx > 0.0 && fy > 0.0) {
            return Err(FormatError::at_key(
                path,
                key("fx"),
                "focal lengths must be positive",
            ));
        }
        Ok(Intrinsics {
            width,
            height,
            fx,
            fy,
            skew,
            cx,
            cy,
            dist,
        })
    }

    /// The inline form of a camera.
    fn inline(name: &str, c: &Camera) -> Self {
        let k = &c.intrinsics;
        let two_term = k.dist.is_two_term_radial();
        Self {
            name: name.to_string(),
            width: Some(k.width),
            height: Some(k.height),
            fx: Some(k.fx),
            fy: Some(k.fy),
            skew: Some(k.skew),
            cx: Some(k.cx),
            cy: Some(k.cy),
            k1: two_term.then_some(k.dist.k1),
            k2: two_term.then_some(k.dist.k2),
            dist: (!two_term).then(|| k.dist.coefficients()),
            camera_from_world: mat3_row_major(&c.camera_from_world),
            center: c.center.into(),
            ..Self::default()
        }
    }
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ArmEntry {
    world_from_base: [f64; 16],
    #[serde(default)]
    tool: [f64; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    urdf: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    base_link: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    tip_link: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    joints: Option<Vec<JointEntry>>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct JointEntry {
    a: f64,
    alpha: f64,
    d: f64,
    #[serde(default)]
    theta_offset: f64,
    #[serde(default = "default_min")]
    min: f64,
    #[serde(default = "default_max")]
    max: f64,
}

/// Joints a joint state message carries.
const MAX_ARM_JOINTS: usize = 8;

impl From<&JointEntry> for DhJoint {
    fn from(j: &JointEntry) -> Self {
        Self {
            a: j.a,
            alpha: j.alpha,
            d: j.d,
            theta_offset: j.theta_offset,
            min: j.min,
            max: j.max,
        }
    }
}

impl From<&DhJoint> for JointEntry {
    fn from(j: &DhJoint) -> Self {
        Self {
            a: j.a,
            alpha: j.alpha,
            d: j.d,
            theta_offset: j.theta_offset,
            min: j.min,
            max: j.max,
        }
    }
}

fn default_min() -> f64 {
    -std::f64::consts::PI
}

fn default_max() -> f64 {
    std::f64::consts::PI
}

/// Reads and validates a rig file.
pub fn read(path: impl AsRef<Path>) -> Result<Rig, FormatError> {
    let path = path.as_ref();
    parse(path, &read_text(path)?)
}

/// Parses rig TOML text; `path` is only used in error messages.
pub fn parse(path: &Path, text: &str) -> Result<Rig, FormatError> {
    let file = rig_file(path, text)?;
    if file.camera.len() != 2 {
        return Err(FormatError::at_key(
            path,
            "camera",
            format!(
                "expected 2 [[camera]] tables (left, right), found {}",
                file.camera.len()
            ),
        ));
    }
    let mut cameras = Vec::with_capacity(2);
    for (i, c) in file.camera.iter().enumerate() {
        let key = |k: &str| format!("camera[{i}].{k}");
        let intrinsics = c.intrinsics(path, i)?;
        check_finite(path, &key("center"), &c.center)?;
        let r = mat3(&c.camera_from_world);
        check_rotation(path, &key("camera_from_world"), &r, false)?;
        cameras.push(Camera::new(intrinsics, r, Vector3::from(c.center)));
    }
    let arm = file.arm.as_ref().map(|a| parse_arm(path, a)).transpose()?;
    if let Some(sigma) = file.pixel_sigma
        && !(sigma.is_finite() && sigma > 0.0)
    {
        return Err(FormatError::at_key(
            path,
            "pixel_sigma",
            format!("must be a positive number of pixels, found {sigma}"),
        ));
    }
    Ok(Rig {
        names: [file.camera[0].name.clone(), file.camera[1].name.clone()],
        cameras: [cameras[0], cameras[1]],
        arm,
        pixel_sigma: file.pixel_sigma,
    })
}

fn parse_arm(path: &Path, a: &ArmEntry) -> Result<Arm, FormatError> {
    let world_from_base = crate::parse_pose(path, "arm.world_from_base", &a.world_from_base)?;
    check_finite(path, "arm.tool", &a.tool)?;
    let model = match (&a.urdf, &a.joints) {
        (Some(_), Some(_)) => {
            return Err(FormatError::at_key(
                path,
                "arm.joints",
                "given beside arm.urdf; describe the arm by one or the other",
            ));
        }
        (None, None) => {
            return Err(FormatError::at_key(
                path,
                "arm",
                "describe the arm by joints = [DH rows] or urdf = \"FILE\" with base_link and tip_link",
            ));
        }
        (Some(file), None) => ArmModel::Chain(urdf_chain(path, file, a)?),
        (None, Some(rows)) => {
            if a.base_link.is_some() || a.tip_link.is_some() {
                return Err(FormatError::at_key(
                    path,
                    "arm.base_link",
                    "base_link and tip_link only apply to a URDF arm",
                ));
            }
            ArmModel::Dh(parse_dh(path, rows)?)
        }
    };
    Ok(Arm {
        world_from_base,
        model,
        tool: Vector3::from(a.tool),
    })
}

/// The chain of `[arm] urdf = FILE` (relative to the rig's folder).
fn urdf_chain(path: &Path, file: &str, a: &ArmEntry) -> Result<geometry::Chain, FormatError> {
    let link = |key: &str, v: &Option<String>| {
        v.clone().ok_or_else(|| {
            FormatError::at_key(
                path,
                format!("arm.{key}"),
                "missing: a URDF arm needs base_link and tip_link",
            )
        })
    };
    let (base, tip) = (
        link("base_link", &a.base_link)?,
        link("tip_link", &a.tip_link)?,
    );
    let file = path.parent().unwrap_or(Path::new("")).join(file);
    let mut chain = crate::urdf::read(&file, &base, &tip)
        .map_err(|e| FormatError::at_key(path, "arm.urdf", e.to_string()))?;
    // Absolute, so that a rig written from this one works from any folder.
    if let (Some(source), Ok(absolute)) = (chain.source.as_mut(), std::fs::canonicalize(&file)) {
        source.urdf = absolute.display().to_string();
    }
    if chain.inputs.len() > MAX_ARM_JOINTS {
        return Err(FormatError::at_key(
            path,
            "arm.urdf",
            format!(
                "the chain from {base:?} to {tip:?} has {} joints; at most {MAX_ARM_JOINTS} are supported",
                chain.inputs.len()
            ),
        ));
    }
    Ok(chain)
}

fn parse_dh(path: &Path, rows: &[JointEntry]) -> Result<Vec<DhJoint>, FormatError> {
    if rows.is_empty() {
        return Err(FormatError::at_key(
            path,
            "arm.joints",
            "the arm has no joints",
        ));
    }
    if rows.len() > MAX_ARM_JOINTS {
        return Err(FormatError::at_key(
            path,
            "arm.joints",
            format!(
                "{} joints; at most {MAX_ARM_JOINTS} are supported",
                rows.len()
            ),
        ));
    }
    let mut joints = Vec::with_capacity(rows.len());
    for (i, j) in rows.iter().enumerate() {
        check_finite(
            path,
            &format!("arm.joints[{i}]"),
            &[j.a, j.alpha, j.d, j.theta_offset, j.min, j.max],
        )?;
        if j.min > j.max {
            return Err(FormatError::at_key(
                path,
                format!("arm.joints[{i}].min"),
                "min is above max",
            ));
        }
        joints.push(DhJoint::from(j));
    }
    Ok(joints)
}

/// The rig file's TOML, or an error naming its line.
fn rig_file(path: &Path, text: &str) -> Result<RigFile, FormatError> {
    toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|s| 1 + text[..s.start.min(text.len())].matches('\n').count());
        FormatError::new(path, line.map(|l| format!("line {l}")), e.message())
    })
}

/// The files the rig text `text` of the file at `path` refers to (camera
/// calibration files, the URDF), resolved against its folder: what a copy
/// of the rig needs beside it.
pub fn referenced_files(path: &Path, text: &str) -> Result<Vec<std::path::PathBuf>, FormatError> {
    let file = rig_file(path, text)?;
    let dir = path.parent().unwrap_or(Path::new(""));
    Ok(file
        .camera
        .iter()
        .filter_map(|c| c.calibration.as_deref())
        .chain(file.arm.as_ref().and_then(|a| a.urdf.as_deref()))
        .map(|f| dir.join(f))
        .collect())
}

/// Renders a rig as TOML.
pub fn to_toml(rig: &Rig) -> String {
    let camera = rig
        .cameras
        .iter()
        .zip(&rig.names)
        .map(|(c, name)| CameraEntry::inline(name, c))
        .collect();
    let arm = rig.arm.as_ref().map(|a| {
        let world_from_base = crate::pose_row_major(&a.world_from_base);
        let (urdf, base_link, tip_link, joints) = match &a.model {
            ArmModel::Dh(rows) => (
                None,
                None,
                None,
                Some(rows.iter().map(JointEntry::from).collect()),
            ),
            ArmModel::Chain(c) => {
                let s = c.source.as_ref().expect("a chain arm comes from a URDF");
                let urdf = s.urdf.clone();
                (
                    Some(urdf),
                    Some(s.base_link.clone()),
                    Some(s.tip_link.clone()),
                    None,
                )
            }
        };
        ArmEntry {
            world_from_base,
            tool: a.tool.into(),
            urdf,
            base_link,
            tip_link,
            joints,
        }
    });
    toml::to_string(&RigFile {
        pixel_sigma: rig.pixel_sigma,
        camera,
        arm,
    })
    .expect("a rig always serialises")
}

/// Writes a rig file.
pub fn write(path: impl AsRef<Path>, rig: &Rig) -> Result<(), FormatError> {
    write_text(path.as_ref(), &to_toml(rig))
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::sim::nico_scene;

    #[test]
    fn nico_rig_round_trips() {
        let rig = nico_scene().rig;
        let back = parse(Path::new("rig.toml"), &to_toml(&rig)).unwrap();
        assert_eq!(back.names, rig.names);
        for k in 0..2 {
            assert_eq!(back.cameras[k].intrinsics, rig.cameras[k].intrinsics);
            assert!(
                (back.cameras[k].camera_from_world - rig.cameras[k].camera_from_world).norm()
                    < 1e-12
            );
        }
        let (a, b) = (back.arm.unwrap(), rig.arm.unwrap());
        let q = [0.5, -0.2, 0.3, 0.4];
        assert!(
            (a.end_effector(&q, &[]).unwrap() - b.end_effector(&q, &[]).unwrap()).norm() < 1e-9
        );
    }

    #[test]
    fn errors_name_the_line_or_key() {
        let good = to_toml(&nico_scene().rig);
        let p = Path::new("r.toml");
        let bad_syntax = good.replacen("fx = ", "fx = = ", 1);
        let e = parse(p, &bad_syntax).unwrap_err().to_string();
        assert!(e.starts_with("r.toml: line "), "{e}");
        let missing = good.replacen("fy = ", "fyy = ", 1);
        let e = parse(p, &missing).unwrap_err().to_string();
        assert!(e.contains("fyy") && !e.contains('\n'), "{e}");
        let start = good.find("camera_from_world = [").unwrap();
        let end = start + good[start..].find(']').unwrap() + 1;
        let scaled = format!(
            "{}camera_from_world = [2, 0, 0, 0, 1, 0, 0, 0, 1]{}",
            &good[..start],
            &good[end..]
        );
        let e = parse(p, &scaled).unwrap_err().to_string();
        assert!(
            e.starts_with("r.toml: key camera[0].camera_from_world: is not a rotation"),
            "{e}"
        );
        let one_camera = good
            .split("[[camera]]")
            .take(2)
            .collect::<Vec<_>>()
            .join("[[camera]]");
        let e = parse(p, &one_camera).unwrap_err().to_string();
        assert!(e.contains("key camera") && e.contains("found 1"), "{e}");
    }

    #[test]
    fn distortion_is_inline_in_either_form_or_from_a_calibration_file() {
        let dir = tempfile::tempdir().unwrap();
        let good = to_toml(&nico_scene().rig);
        // The second camera's intrinsics come from a ROS file beside the rig.
        let mut rig = nico_scene().rig;
        rig.cameras[1].intrinsics.dist =
            Distortion::from_opencv(&[-0.2, 0.05, 0.001, -0.002, 0.01, 0.1, 0.02, 0.003]).unwrap();
        std::fs::create_dir(dir.path().join("cal")).unwrap();
        std::fs::write(
            dir.path().join("cal/right.yaml"),
            crate::camera_file::to_ros_yaml("right", &rig.cameras[1].intrinsics),
        )
        .unwrap();
        let second = good.rfind("[[camera]]").unwrap();
        let (head, tail) = good.split_at(second);
        let pose: String = tail
            .lines()
            .filter(|l| l.starts_with("camera_from_world") || l.starts_with("center"))
            .map(|l| format!("{l}\n"))
            .collect();
        let by_file =
            format!("{head}[[camera]]\nname = \"right\"\ncalibration = \"cal/right.yaml\"\n{pose}");
        let path = dir.path().join("rig.toml");
        std::fs::write(&path, &by_file).unwrap();
        let read = read(&path).unwrap();
        assert_eq!(read.cameras[1].intrinsics, rig.cameras[1].intrinsics);
        // Written back, a full model is inline as `dist` and reads the same.
        let inline = to_toml(&read);
        assert!(inline.contains("dist = ["), "{inline}");
        let back = parse(Path::new("r.toml"), &inline).unwrap();
        assert_eq!(back.cameras[1].intrinsics, rig.cameras[1].intrinsics);
        // Conflicts and missing keys name the key.
        let both = by_file.replace("calibration = ", "fx = 500.0\ncalibration = ");
        let e = parse(&path, &both).unwrap_err().to_string();
        assert!(
            e.contains("key camera[1].fx: given beside calibration"),
            "{e}"
        );
        let missing = by_file.replace("cal/right.yaml", "cal/none.yaml");
        let e = parse(&path, &missing).unwrap_err().to_string();
        assert!(
            e.contains("key camera[1].calibration: ") && e.contains("none.yaml: cannot read"),
            "{e}"
        );
        let k_and_dist = good.replacen("k1 = ", "dist = [0.1, 0.0, 0.0, 0.0]\nk1 = ", 1);
        let e = parse(&path, &k_and_dist).unwrap_err().to_string();
        assert!(e.contains("key camera[0].dist: given beside k1/k2"), "{e}");
        let three = good.replacen("k1 = ", "dist = [0.1, 0.0, 0.0]\nkk = ", 1);
        let e = parse(&path, &three.replacen("k2 = ", "kk2 = ", 1))
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown field"), "{e}");
        let no_fx = good.replacen("fx = ", "# fx = ", 1);
        let e = parse(&path, &no_fx).unwrap_err().to_string();
        assert!(e.contains("key camera[0].fx: missing"), "{e}");
    }
}
