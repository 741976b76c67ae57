//! One mirror plane shared by both cameras, optionally with encoder offsets.
//!
//! Parameters: the plane's normal as a 2-D step in the tangent plane of the
//! initial normal, its offset `d`, and (with kinematics) one offset per joint.
//! Residuals: each sample's end-effector model point, reflected in the plane
//! and projected through each real camera, against the detections; the same
//! as projecting it through the mirror cameras the plane implies.

use geometry::{GeometryError, Plane, Rig, lsq};
use nalgebra::{DVector, Vector3};

use super::{
    CalibrateError, Calibration, Method, Observation, check_plane_clear_of_cameras, rms_px,
};

/// Refines from `start`, the plane midway between the J's and Ĵ's.
pub(super) fn calibrate(
    rig: &Rig,
    obs: &[Observation],
    start: Plane,
    with_kinematics: bool,
) -> Result<Calibration, CalibrateError> {
    let n0 = start.normal.into_inner();
    // Tangent basis at n0.
    let helper = if n0.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let t1 = n0.cross(&helper).normalize();
    let t2 = n0.cross(&t1);
    let plane_at = |x: &DVector<f64>| Plane::new(n0 + t1 * x[0] + t2 * x[1], x[2]);

    let arm = rig.arm.as_ref();
    let dof = if with_kinematics {
        arm.map_or(0, |a| a.dof())
    } else {
        0
    };
    let points_at = |x: &DVector<f64>| -> Option<Vec<Vector3<f64>>> {
        if dof == 0 {
            return Some(obs.iter().map(|o| o.model_point).collect());
        }
        let arm = arm?;
        let offsets: Vec<f64> = (0..dof).map(|j| x[3 + j]).collect();
        obs.iter()
            .map(|o| arm.end_effector(o.joints.as_ref()?, &offsets).ok())
            .collect()
    };
    let residuals = |x: &DVector<f64>| -> Option<DVector<f64>> {
        let plane = plane_at(x).ok()?;
        let points = points_at(x)?;
        let mut r = DVector::zeros(4 * obs.len());
        for (i, (o, p)) in obs.iter().zip(&points).enumerate() {
            let virtual_point = plane.reflect_point(p);
            for k in 0..2 {
                let d = rig.cameras[k].project(&virtual_point).ok()? - o.pixels[k];
                r[4 * i + 2 * k] = d.x;
                r[4 * i + 2 * k + 1] = d.y;
            }
        }
        Some(r)
    };
    let mut x0 = DVector::zeros(3 + dof);
    x0[2] = start.distance;
    let (x, _) = lsq::minimize(x0, residuals)?;
    let plane = plane_at(&x)?;
    check_plane_clear_of_cameras(rig, &plane)?;
    let r = residuals(&x).ok_or(GeometryError::NonFinite("joint refinement residuals"))?;
    let mirror = |p: &Plane| {
        [
            p.mirror_camera(&rig.cameras[0]),
            p.mirror_camera(&rig.cameras[1]),
        ]
    };
    Ok(Calibration {
        method: if with_kinematics {
            Method::JointKinematics
        } else {
            Method::Joint
        },
        plane: Some(plane),
        mirror_cameras: mirror(&plane),
        joint_offsets: with_kinematics.then(|| (0..dof).map(|j| x[3 + j]).collect()),
        initial_cameras: mirror(&start),
        train_rms_px: rms_px(&r),
        samples: obs.len(),
    })
}
