//! A calibration in standard forms, for tools other than ours:
//!
//! - [`mirror_json`]: the mirror plane and the mirror cameras with their
//!   poses as rigid transforms (translation, quaternion) and projection
//!   matrices, in the world (stereo head) frame, mm;
//! - [`frame_transforms_json`]: the same frames as a Foxglove
//!   `foxglove.FrameTransforms` message in its JSON encoding (metres), a
//!   snapshot any Foxglove panel or `ros2`-style tool can load;
//! - [`corrected_dh_rig`]: a DH rig with the estimated joint offsets folded
//!   into `theta_offset` (for a URDF arm, [`crate::urdf::corrected`]).

use geometry::{ArmModel, Camera, Rig};
use nalgebra::Isometry3;
use serde_json::{Value, json};

use crate::calibration::CalibrationFile;

/// Frame names, shared with the live view.
pub const WORLD_FRAME: &str = "world";
/// The real cameras' frames, left then right.
pub const CAMERA_FRAMES: [&str; 2] = ["camera_left", "camera_right"];
/// The mirror cameras' frames, left then right.
pub const MIRROR_CAMERA_FRAMES: [&str; 2] = ["mirror_camera_left", "mirror_camera_right"];
/// The mirror plane's frame (origin at the foot of the world origin, z along the normal).
pub const MIRROR_FRAME: &str = "mirror";

fn pose_json(t: &Isometry3<f64>, scale: f64) -> (Value, Value) {
    let v = t.translation.vector * scale;
    let q = t.rotation;
    (
        json!({"x": v.x, "y": v.y, "z": v.z}),
        json!({"x": q.i, "y": q.j, "z": q.k, "w": q.w}),
    )
}

/// The frames of a calibration: `(child frame, world_from_child)`.
fn frames(cal: &CalibrationFile, rig: &Rig) -> Vec<(&'static str, Isometry3<f64>)> {
    let mut out = Vec::new();
    if let Some(plane) = cal.plane() {
        out.push((MIRROR_FRAME, plane.world_from_plane()));
    }
    for (k, cam) in cal.mirror_cameras(rig).iter().enumerate() {
        out.push((MIRROR_CAMERA_FRAMES[k], cam.world_from_camera()));
    }
    for (k, cam) in rig.cameras.iter().enumerate() {
        out.push((CAMERA_FRAMES[k], cam.world_from_camera()));
    }
    out
}

fn camera_json(name: &str, frame: &str, cam: &Camera) -> Value {
    let pose = cam.world_from_camera();
    let (translation, rotation) = pose_json(&pose, 1.0);
    let p = cam.projection_matrix();
    json!({
        "name": name,
        "frame": frame,
        "camera_from_world": crate::mat3_row_major(&cam.camera_from_world),
        "center": [cam.center.x, cam.center.y, cam.center.z],
        "world_from_camera": {"translation": translation, "rotation": rotation},
        "projection_matrix": (0..3).flat_map(|r| (0..4).map(move |c| p[(r, c)])).collect::<Vec<f64>>(),
    })
}

/// The mirror plane and mirror cameras as JSON (mm, world frame).
pub fn mirror_json(cal: &CalibrationFile, rig: &Rig) -> String {
    let cameras: Vec<Value> = cal
        .mirror_cameras(rig)
        .iter()
        .enumerate()
        .map(|(k, c)| camera_json(&rig.names[k], MIRROR_CAMERA_FRAMES[k], c))
        .collect();
    let plane = cal.plane().map(|p| {
        let (translation, rotation) = pose_json(&p.world_from_plane(), 1.0);
        json!({
            "normal": [p.normal.x, p.normal.y, p.normal.z],
            "distance": p.distance,
            "frame": MIRROR_FRAME,
            "world_from_plane": {"translation": translation, "rotation": rotation},
        })
    });
    let doc = json!({
        "frame": WORLD_FRAME,
        "units": {"length": "mm", "angle": "rad"},
        "method": cal.method,
        "plane": plane,
        "mirror_cameras": cameras,
        "joint_names": cal.joint_names,
        "joint_offsets": cal.joint_offsets,
        "train_rms_px": cal.train_rms_px,
        "samples": cal.samples,
    });
    serde_json::to_string_pretty(&doc).expect("JSON values serialise") + "\n"
}

/// The calibration's frames as a `foxglove.FrameTransforms` message in
/// JSON (metres, parent `world`, stamp 0).
pub fn frame_transforms_json(cal: &CalibrationFile, rig: &Rig) -> String {
    let transforms: Vec<Value> = frames(cal, rig)
        .into_iter()
        .map(|(child, pose)| {
            let (translation, rotation) = pose_json(&pose, 1e-3);
            json!({
                "timestamp": {"sec": 0, "nsec": 0},
                "parent_frame_id": WORLD_FRAME,
                "child_frame_id": child,
                "translation": translation,
                "rotation": rotation,
            })
        })
        .collect();
    serde_json::to_string_pretty(&json!({ "transforms": transforms }))
        .expect("JSON values serialise")
        + "\n"
}

/// A DH rig with `offsets` folded into each joint's `theta_offset`; `None`
/// if the rig's arm is not a DH table of as many joints.
pub fn corrected_dh_rig(rig: &Rig, offsets: &[f64]) -> Option<Rig> {
    let mut out = rig.clone();
    let arm = out.arm.as_mut()?;
    let ArmModel::Dh(joints) = &mut arm.model else {
        return None;
    };
    if joints.len() != offsets.len() {
        return None;
    }
    for (j, o) in joints.iter_mut().zip(offsets) {
        j.theta_offset += o;
    }
    Some(out)
}
