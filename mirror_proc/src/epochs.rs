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
use geometry::register::{Turn, camera_turn_weighted};
use geometry::{Rig, Sample, View};
use nalgebra::{Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::calibrate::{Calibration, model_point};
use crate::drift::Moved;
use crate::still::StillPair;

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
/// The corners of markers that held still (`still_markers`,
/// [`crate::still`]) join in, each put on the ray along which the camera
/// saw it before the knock: a turn moves it in the image alike at any
/// depth. Averaged over the frames on either side, they weigh far more
/// than the arm's views; a marker whose own turn disagrees with the arm's
/// views' (it moved too) is left out.
///
/// Returns the camera as found, with its turn's covariance.
#[allow(clippy::too_many_arguments)]
pub fn find_camera(
    rig: &Rig,
    cal: &Calibration,
    samples: &[Sample],
    still_markers: &[StillPair],
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
        let d = other.ray(px).ok()?;
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
    let found = turn_with_still_markers(
        &rig.cameras[k],
        &points,
        &pixels,
        pixel_sigma,
        still_markers,
    )
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

/// A still marker whose turn differs from the arm's views' by more than
/// this (the squared Mahalanobis distance under both covariances;
/// chi-square, 3 degrees of freedom, at 99.9%) moved.
const STILL_MOVED_CHI2: f64 = 16.27;

/// [`camera_turn_weighted`] of `camera` from the arm's `points` seen at
/// `pixels` (`pixel_sigma` each) and the corners of the `still` markers
/// whose own turn agrees with the arm's views' (a marker that moved
/// turns its own way: judged against the arm alone, since one moved
/// marker pulls a joint fit away from the others).
fn turn_with_still_markers(
    camera: &geometry::Camera,
    points: &[Vector3<f64>],
    pixels: &[Vector2<f64>],
    pixel_sigma: f64,
    still: &[StillPair],
) -> Result<Turn, geometry::GeometryError> {
    let arm = camera_turn_weighted(camera, points, pixels, &vec![pixel_sigma; points.len()])?;
    // Each group weighs with the noise its own fit shows, not less than
    // stated: pooled, the many small residuals of one would vouch for the
    // other's.
    let shown = |t: &Turn, stated: f64, n: usize| {
        let dof = (2 * n).saturating_sub(3).max(1) as f64;
        stated.max((t.rms_px.powi(2) * n as f64 / dof).sqrt())
    };
    let arm_sigma = shown(&arm, pixel_sigma, points.len());
    // A still corner as a point: on the ray it was seen along, at 1 m.
    let on_ray = |px: &Vector2<f64>| Some(camera.center + camera.ray(px).ok()? * 1000.0);
    let (mut p, mut px) = (points.to_vec(), pixels.to_vec());
    let mut sigmas = vec![arm_sigma; points.len()];
    let mut joined = 0;
    for m in still {
        let Some(rays) = (0..4)
            .map(|c| on_ray(&m.before[c]))
            .collect::<Option<Vec<_>>>()
        else {
            continue;
        };
        let Ok(own) = camera_turn_weighted(camera, &rays, &m.after, &[m.sigma_px; 4]) else {
            continue;
        };
        let d = own.w - arm.w;
        let agrees = (arm.covariance + own.covariance)
            .try_inverse()
            .is_some_and(|s| (d.transpose() * s * d)[(0, 0)] < STILL_MOVED_CHI2);
        if agrees {
            p.extend(rays);
            px.extend(m.after);
            sigmas.extend([shown(&own, m.sigma_px, 4); 4]);
            joined += 1;
        }
    }
    if joined == 0 {
        return Ok(arm);
    }
    camera_turn_weighted(camera, &p, &px, &sigmas)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::still::StillMarkers;
    use geometry::sim::nico_scene;
    use messages::{CameraMarkers, Marker, StereoDetections};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A knocked camera's turn from ten of the arm's points, clustered in
    /// the image as direct views are, at 0.2 px; and with a still marker's
    /// corners over 150 frames on either side (0.05 px a frame), with a
    /// second marker that moved (3 px) as well. The still corners cut the
    /// stated sigma about the optical axis by more than half and bring the
    /// turn within 0.02 deg (less than half the arm's own error), inside 4 stated
    /// sigmas; the moved marker is left out (the turn is the same without
    /// it).
    #[test]
    fn still_markers_pin_a_knocked_cameras_turn() {
        let camera = nico_scene().rig.cameras[0];
        let truth = Vector3::new(0.02, 0.3, 0.04).map(f64::to_radians);
        let knocked = camera.turned(&truth);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let arm = Normal::new(0.0, 0.2).unwrap();
        let frame = Normal::new(0.0, 0.05).unwrap();
        let at = |x: f64, y: f64, depth: f64| {
            camera.center + camera.camera_from_world.transpose() * Vector3::new(x, y, 1.0) * depth
        };
        let points: Vec<Vector3<f64>> = (0..10)
            .map(|i| {
                let t = f64::from(i);
                at(
                    0.1 * (1.3 * t).sin(),
                    0.08 * (0.7 * t).cos(),
                    380.0 + 8.0 * t,
                )
            })
            .collect();
        let pixels: Vec<Vector2<f64>> = points
            .iter()
            .map(|p| {
                let noise = Vector2::new(arm.sample(&mut rng), arm.sample(&mut rng));
                knocked.project(p).unwrap() + noise
            })
            .collect();
        // A still marker far off (its 60 mm code at 1.1 m), and one that moves.
        let marker = |x: f64, y: f64| -> [Vector3<f64>; 4] {
            let c = at(x, y, 1100.0);
            [(-30.0, -30.0), (30.0, -30.0), (30.0, 30.0), (-30.0, 30.0)].map(|(dx, dy)| {
                c + camera.camera_from_world.transpose() * Vector3::new(dx, dy, 0.0)
            })
        };
        let (still_marker, moving) = (marker(0.25, 0.12), marker(-0.2, -0.1));
        let mut seen = StillMarkers::new();
        for i in 0..300i64 {
            let cam = if i < 150 { &camera } else { &knocked };
            let mut markers = CameraMarkers::default();
            for (id, corners) in [(7, &still_marker), (8, &moving)] {
                let shift = if id == 8 && i >= 150 { 3.0 } else { 0.0 };
                let mut c = [0.0; 8];
                for (j, p) in corners.iter().enumerate() {
                    let px = cam.project(p).unwrap();
                    c[2 * j] = px.x + shift + frame.sample(&mut rng);
                    c[2 * j + 1] = px.y + frame.sample(&mut rng);
                }
                markers.push(Marker {
                    id,
                    mirrored: 1,
                    corners: c,
                    center: [0.0; 2],
                });
            }
            let mut d = StereoDetections {
                stamp_ns: i,
                ..StereoDetections::default()
            };
            d.cameras[0] = markers;
            seen.push(&d, 0);
        }
        let pairs = seen.pairs(0, 0..=149, 150);
        assert_eq!(pairs.len(), 2);
        let error = |t: &Turn| (t.w - truth).norm().to_degrees();
        let arm_only = turn_with_still_markers(&camera, &points, &pixels, 0.2, &[]).unwrap();
        let with = turn_with_still_markers(&camera, &points, &pixels, 0.2, &pairs).unwrap();
        let still_only = pairs
            .iter()
            .filter(|p| p.id == 7)
            .cloned()
            .collect::<Vec<_>>();
        let without_moved =
            turn_with_still_markers(&camera, &points, &pixels, 0.2, &still_only).unwrap();
        let total_sigma = |t: &Turn| t.covariance.trace().sqrt().to_degrees();
        assert!(
            with.sigma_deg[2] < 0.5 * arm_only.sigma_deg[2],
            "about the optical axis: {:?} with the still marker, {:?} without",
            with.sigma_deg,
            arm_only.sigma_deg
        );
        assert!(
            error(&with) < 0.02 && error(&with) < 4.0 * total_sigma(&with),
            "{} deg off, 1-sigma {} deg (arm only: {} deg off)",
            error(&with),
            total_sigma(&with),
            error(&arm_only)
        );
        assert!(
            error(&arm_only) > 2.0 * error(&with),
            "{}",
            error(&arm_only)
        );
        assert!((with.w - without_moved.w).norm().to_degrees() < 1e-6);
    }
}
