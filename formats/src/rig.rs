//! The rig file (TOML): both cameras and, optionally, the arm's DH model.
//!
//! ```toml
//! [[camera]]                      # first = left, second = right
//! name = "left"
//! width = 640
//! height = 480
//! fx = 550.0
//! fy = 550.0
//! skew = 0.0
//! cx = 320.0
//! cy = 240.0
//! k1 = -0.25
//! k2 = 0.08
//! camera_from_world = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]  # row-major R
//! center = [-30.0, 0.0, 0.0]      # C in world, mm
//!
//! [arm]
//! world_from_base = [1.0, 0.0, 0.0, 0.0,  0.0, 1.0, 0.0, 0.0,  0.0, 0.0, 1.0, 0.0,  0.0, 0.0, 0.0, 1.0]
//! tool = [0.0, 0.0, 0.0]          # marker centre in the last link's frame
//! joints = [
//!   { a = 0.0, alpha = 1.5707963, d = 0.0, theta_offset = 0.0, min = -1.0, max = 1.0 },
//! ]
//! ```

use std::path::Path;

use geometry::{Arm, Camera, DhJoint, Intrinsics, Rig};
use nalgebra::{Isometry3, Matrix4, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::{
    FormatError, check_finite, check_rotation, mat3, mat3_row_major, read_text, write_text,
};

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigFile {
    camera: Vec<CameraEntry>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    arm: Option<ArmEntry>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraEntry {
    name: String,
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    #[serde(default)]
    skew: f64,
    cx: f64,
    cy: f64,
    #[serde(default)]
    k1: f64,
    #[serde(default)]
    k2: f64,
    camera_from_world: [f64; 9],
    center: [f64; 3],
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ArmEntry {
    world_from_base: [f64; 16],
    #[serde(default)]
    tool: [f64; 3],
    joints: Vec<JointEntry>,
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
    let file: RigFile = toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|s| 1 + text[..s.start.min(text.len())].matches('\n').count());
        FormatError::new(path, line.map(|l| format!("line {l}")), e.message())
    })?;
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
        check_finite(
            path,
            &key("intrinsics"),
            &[c.fx, c.fy, c.skew, c.cx, c.cy, c.k1, c.k2],
        )?;
        check_finite(path, &key("center"), &c.center)?;
        if c.width == 0 || c.height == 0 {
            return Err(FormatError::at_key(
                path,
                key("width"),
                "image size must be positive",
            ));
        }
        if !(c.fx > 0.0 && c.fy > 0.0) {
            return Err(FormatError::at_key(
                path,
                key("fx"),
                "focal lengths must be positive",
            ));
        }
        let r = mat3(&c.camera_from_world);
        check_rotation(path, &key("camera_from_world"), &r, false)?;
        let intrinsics = Intrinsics {
            width: c.width,
            height: c.height,
            fx: c.fx,
            fy: c.fy,
            skew: c.skew,
            cx: c.cx,
            cy: c.cy,
            k1: c.k1,
            k2: c.k2,
        };
        cameras.push(Camera::new(intrinsics, r, Vector3::from(c.center)));
    }
    let arm = file.arm.as_ref().map(|a| parse_arm(path, a)).transpose()?;
    Ok(Rig {
        names: [file.camera[0].name.clone(), file.camera[1].name.clone()],
        cameras: [cameras[0], cameras[1]],
        arm,
    })
}

fn parse_arm(path: &Path, a: &ArmEntry) -> Result<Arm, FormatError> {
    check_finite(path, "arm.world_from_base", &a.world_from_base)?;
    check_finite(path, "arm.tool", &a.tool)?;
    let m = Matrix4::from_row_slice(&a.world_from_base);
    if (m.row(3) - nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0)).norm() > 1e-9 {
        return Err(FormatError::at_key(
            path,
            "arm.world_from_base",
            "last row must be [0, 0, 0, 1]",
        ));
    }
    let r = m.fixed_view::<3, 3>(0, 0).into_owned();
    check_rotation(path, "arm.world_from_base", &r, false)?;
    if a.joints.is_empty() {
        return Err(FormatError::at_key(
            path,
            "arm.joints",
            "the arm has no joints",
        ));
    }
    let mut joints = Vec::with_capacity(a.joints.len());
    for (i, j) in a.joints.iter().enumerate() {
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
        joints.push(DhJoint {
            a: j.a,
            alpha: j.alpha,
            d: j.d,
            theta_offset: j.theta_offset,
            min: j.min,
            max: j.max,
        });
    }
    Ok(Arm {
        world_from_base: Isometry3::from_parts(
            Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
        ),
        joints,
        tool: Vector3::from(a.tool),
    })
}

/// Renders a rig as TOML.
pub fn to_toml(rig: &Rig) -> String {
    let camera = rig
        .cameras
        .iter()
        .zip(&rig.names)
        .map(|(c, name)| CameraEntry {
            name: name.clone(),
            width: c.intrinsics.width,
            height: c.intrinsics.height,
            fx: c.intrinsics.fx,
            fy: c.intrinsics.fy,
            skew: c.intrinsics.skew,
            cx: c.intrinsics.cx,
            cy: c.intrinsics.cy,
            k1: c.intrinsics.k1,
            k2: c.intrinsics.k2,
            camera_from_world: mat3_row_major(&c.camera_from_world),
            center: c.center.into(),
        })
        .collect();
    let arm = rig.arm.as_ref().map(|a| {
        let m = a.world_from_base.to_homogeneous();
        let mut world_from_base = [0.0; 16];
        for r in 0..4 {
            for c in 0..4 {
                world_from_base[4 * r + c] = m[(r, c)];
            }
        }
        ArmEntry {
            world_from_base,
            tool: a.tool.into(),
            joints: a
                .joints
                .iter()
                .map(|j| JointEntry {
                    a: j.a,
                    alpha: j.alpha,
                    d: j.d,
                    theta_offset: j.theta_offset,
                    min: j.min,
                    max: j.max,
                })
                .collect(),
        }
    });
    toml::to_string(&RigFile { camera, arm }).expect("a rig always serialises")
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
}
