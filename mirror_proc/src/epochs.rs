//! After the world changed: what the live stage calibrates again from.
//!
//! A change found by the [`crate::drift`] watch ends an epoch: the samples
//! from before it are set aside (kept in the journal and the recording,
//! not used), and the next epoch is calibrated from the samples that
//! follow. A moved mirror is calibrated again from the new mirror views,
//! starting from the old plane. A knocked camera is found again first,
//! from direct views of the arm's marker (whose positions the arm's
//! kinematics and the old calibration's offsets give): its turn, by
//! [`geometry::register::camera_turn`]; the mirror, which did not move,
//! then gives its mirror camera at once.

use formats::calibration::{CalibrationFile, HeadCameraEntry};
use geometry::register::camera_turn;
use geometry::{Rig, Sample, View};
use nalgebra::{Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::calibrate::{Calibration, model_point};
use crate::drift::Moved;

/// Direct views after a camera moved before its pose is found again.
pub const CAMERA_VIEWS: usize = 10;

/// One epoch of a live run: a stretch of poses over which the world held
/// still, and its calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochReport {
    /// Its number, from 1.
    pub epoch: u32,
    /// The pose at which it began (the change before it began there).
    pub began_at_pose: u64,
    /// What changed to begin it (`mirror`, `camera <name>`, `head`); none
    /// for the first.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub after: Option<String>,
    /// Where that change was found.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub found_at_pose: Option<u64>,
    /// Where the change that ended it began; none for the last.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ended_at_pose: Option<u64>,
    /// Training samples paired in it.
    pub train_samples: usize,
    /// Test samples (mirror and direct) paired in it.
    pub test_samples: usize,
    /// Its last calibration, if it got one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationFile>,
}

/// How a change is named in the report and the log.
pub fn describe(moved: &Moved) -> String {
    match moved {
        Moved::Mirror => "mirror".into(),
        Moved::Camera(name) => format!("camera {name}"),
        Moved::Head => "head".into(),
    }
}

/// The cameras a change moved, by index in the rig.
pub fn cameras_moved(rig: &Rig, moved: &Moved) -> Vec<usize> {
    match moved {
        Moved::Mirror => Vec::new(),
        Moved::Camera(name) => rig
            .names
            .iter()
            .position(|n| n == name)
            .into_iter()
            .collect(),
        Moved::Head => vec![0, 1],
    }
}

/// A head camera found again after it moved.
#[derive(Debug, Clone, PartialEq)]
pub struct FoundCamera {
    /// Its entry for the calibration file.
    pub entry: HeadCameraEntry,
    /// Its index in the rig.
    pub index: usize,
    /// The covariance of its turn about its own axes, rad^2: what it adds
    /// to the uncertainty of every calibration that takes it as found.
    pub turn_covariance: Matrix3<f64>,
}

/// Finds camera `k` of `rig` again from the `samples` since it moved, the
/// marker placed by the arm as `cal` (made with `rig`) models it: a direct
/// view sees the marker, a mirror view its reflection in `cal`'s plane
/// (the mirror did not move). Direct views alone cluster where the arm
/// reaches in front of the head, which leaves the turn about the optical
/// axis loose (0.05-0.1 deg from 10); the mirror views lie elsewhere in the
/// image and pin it.
///
/// Where the other camera did not move (`other_still`), each point is
/// taken on the ray along which that camera sees it, at the arm's depth:
/// the arm places the marker to its encoder offsets' accuracy (a
/// millimetre is 0.14 deg at 400 mm), the unmoved camera to a fraction of
/// that across its ray, and the depth left to the arm moves the point
/// across the moved camera's view only by the stereo baseline's share.
///
/// Returns the camera as found, with its turn's covariance.
pub fn find_camera(
    rig: &Rig,
    cal: &Calibration,
    samples: &[Sample],
    k: usize,
    other_still: bool,
    pixel_sigma: f64,
    moved_at_pose: u64,
) -> Result<FoundCamera, String> {
    let corrected = cal.corrected_rig(rig);
    let offsets = cal.joint_offsets.as_deref();
    let other = &rig.cameras[1 - k];
    // Where the unmoved camera sees a point near `p` along its ray through `px`.
    let on_ray = |p: Vector3<f64>, px: &Vector2<f64>| -> Option<Vector3<f64>> {
        let xy = other.intrinsics.undistort_pixel(px).ok()?;
        let d = (other.camera_from_world.transpose() * Vector3::new(xy.x, xy.y, 1.0)).normalize();
        let along = d.dot(&(p - other.center));
        (along > 0.0).then(|| other.center + d * along)
    };
    let mut points = Vec::with_capacity(samples.len());
    let mut pixels = Vec::with_capacity(samples.len());
    for s in samples {
        let Ok(arm_point) = model_point(&corrected, s, offsets) else {
            continue;
        };
        let seen = match (s.view, cal.plane) {
            // The virtual point behind the glass, seen directly by both.
            (View::Mirror, Some(plane)) => Some(plane.reflect_point(&arm_point)),
            (View::Mirror, None) => None,
            (View::Direct, _) => Some(arm_point),
        };
        let seen = match seen {
            Some(p) if other_still => on_ray(p, &s.pixels[1 - k]),
            seen => seen,
        };
        if let Some(p) = seen {
            points.push(p);
            pixels.push(s.pixels[k]);
        }
    }
    let found = camera_turn(&rig.cameras[k], &points, &pixels, pixel_sigma)
        .map_err(|e| format!("cannot find the {} camera again: {e}", rig.names[k]))?;
    let r = found.camera.camera_from_world;
    Ok(FoundCamera {
        entry: HeadCameraEntry {
            name: rig.names[k].clone(),
            camera_from_world: [
                r.m11, r.m12, r.m13, r.m21, r.m22, r.m23, r.m31, r.m32, r.m33,
            ],
            center: found.camera.center.into(),
            turn_deg: found.w.norm().to_degrees(),
            sigma_deg: found.sigma_deg,
            views: samples.iter().filter(|s| s.view == View::Direct).count(),
            moved_at_pose,
        },
        index: k,
        turn_covariance: found.covariance,
    })
}

/// `cal` with its mirror cameras those of `rig`'s cameras in its plane:
/// the mirror did not move, a camera did. `None` without a plane (the
/// paper's method), which must be calibrated again instead.
pub fn reflected_anew(cal: &Calibration, rig: &Rig) -> Option<Calibration> {
    let plane = cal.plane?;
    let mirror_cameras = rig.cameras.map(|c| plane.mirror_camera(&c));
    let mut cal = cal.clone();
    cal.mirror_cameras = mirror_cameras;
    if let Some(first) = cal.placements.first_mut() {
        first.mirror_cameras = mirror_cameras;
    }
    Some(cal)
}
