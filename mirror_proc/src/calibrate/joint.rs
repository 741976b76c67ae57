//! One mirror plane shared by both cameras, optionally with encoder offsets.
//!
//! Parameters: the plane's normal as a 2-D step in the tangent plane of the
//! initial normal, its offset `d`, and (with kinematics) one offset per joint.
//! Residuals: each sample's end-effector model point, reflected in the plane
//! and projected through each real camera, against the detections; the same
//! as projecting it through the mirror cameras the plane implies.

use geometry::{Camera, GeometryError, Plane, Rig, lsq};
use nalgebra::{DVector, Vector3};

use super::uncertainty::{Uncertainty, chart, propagate_to_cameras};
use super::{
    CalibrateError, Calibration, Method, Observation, check_plane_clear_of_cameras, rms_px,
};

/// The plane's parameters: a step `(x0, x1)` in the tangent plane of `n0`
/// (radians, to first order, at zero), then the offset `d`.
struct PlaneChart {
    n0: Vector3<f64>,
    t1: Vector3<f64>,
    t2: Vector3<f64>,
}

impl PlaneChart {
    fn at(n0: Vector3<f64>) -> Self {
        let helper = if n0.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let t1 = n0.cross(&helper).normalize();
        let t2 = n0.cross(&t1);
        Self { n0, t1, t2 }
    }

    fn plane(&self, x: &[f64]) -> Result<Plane, GeometryError> {
        Plane::new(self.n0 + self.t1 * x[0] + self.t2 * x[1], x[2])
    }
}

/// The residuals of parameters `x` (plane in `chart`, then `dof` offsets):
/// per sample and camera, the reflected model point's projection minus the
/// detection.
fn residuals(
    rig: &Rig,
    obs: &[Observation],
    chart: &PlaneChart,
    dof: usize,
    x: &DVector<f64>,
) -> Option<DVector<f64>> {
    let plane = chart.plane(x.as_slice()).ok()?;
    let offsets: Vec<f64> = (0..dof).map(|j| x[3 + j]).collect();
    let mut r = DVector::zeros(4 * obs.len());
    for (i, o) in obs.iter().enumerate() {
        let point = if dof == 0 {
            o.model_point
        } else {
            rig.arm
                .as_ref()?
                .end_effector(o.joints.as_ref()?, &offsets)
                .ok()?
        };
        let virtual_point = plane.reflect_point(&point);
        for k in 0..2 {
            let d = rig.cameras[k].project(&virtual_point).ok()? - o.pixels[k];
            r[4 * i + 2 * k] = d.x;
            r[4 * i + 2 * k + 1] = d.y;
        }
    }
    Some(r)
}

/// Refines from `start`, the plane midway between the J's and Ĵ's.
pub(super) fn calibrate(
    rig: &Rig,
    obs: &[Observation],
    start: Plane,
    with_kinematics: bool,
    prior_sigma: Option<f64>,
) -> Result<Calibration, CalibrateError> {
    let dof = if with_kinematics {
        rig.arm.as_ref().map_or(0, |a| a.dof())
    } else {
        0
    };
    let start_chart = PlaneChart::at(start.normal.into_inner());
    let mut x0 = DVector::zeros(3 + dof);
    x0[2] = start.distance;
    let (x, _) = lsq::minimize(x0, |x| residuals(rig, obs, &start_chart, dof, x))?;
    let plane = start_chart.plane(x.as_slice())?;
    check_plane_clear_of_cameras(rig, &plane)?;
    let r = residuals(rig, obs, &start_chart, dof, &x)
        .ok_or(GeometryError::NonFinite("joint refinement residuals"))?;
    let joint_offsets: Option<Vec<f64>> =
        with_kinematics.then(|| (0..dof).map(|j| x[3 + j]).collect());
    // A fit whose covariance cannot be formed is still a fit: it says so.
    let uncertainty = if let Some(prior_sigma) = prior_sigma {
        uncertainty(
            rig,
            obs,
            &plane,
            joint_offsets.as_deref(),
            dof,
            &r,
            prior_sigma,
        )
        .unwrap_or_else(|e| Uncertainty::not_stated(&e.to_string()))
    } else {
        Uncertainty::not_stated("not asked for")
    };
    Ok(Calibration {
        method: if with_kinematics {
            Method::JointKinematics
        } else {
            Method::Joint
        },
        plane: Some(plane),
        mirror_cameras: mirror_cameras(rig, &plane),
        joint_offsets,
        initial_cameras: mirror_cameras(rig, &start),
        train_rms_px: rms_px(&r),
        samples: obs.len(),
        uncertainty,
        rejected: Vec::new(),
        fit: super::Fit::NotJudged,
    })
}

/// Both mirror cameras that `plane` makes of the rig's cameras.
fn mirror_cameras(rig: &Rig, plane: &Plane) -> [Camera; 2] {
    rig.cameras.map(|c| plane.mirror_camera(&c))
}

/// The covariance at the solution, in a chart centred on the solved normal
/// so that the first two parameters are the normal's tilt in radians;
/// `solved_residuals` are the fit's residuals there, and `prior_sigma` the
/// pixel noise assumed where they have no redundancy to measure it.
fn uncertainty(
    rig: &Rig,
    obs: &[Observation],
    plane: &Plane,
    offsets: Option<&[f64]>,
    dof: usize,
    solved_residuals: &DVector<f64>,
    prior_sigma: f64,
) -> Result<Uncertainty, CalibrateError> {
    let chart_here = PlaneChart::at(plane.normal.into_inner());
    let mut y = DVector::zeros(3 + dof);
    y[2] = plane.distance;
    for (j, o) in offsets.unwrap_or_default().iter().enumerate() {
        y[3 + j] = *o;
    }
    let at = |y: &DVector<f64>| residuals(rig, obs, &chart_here, dof, y);
    let undefined = || GeometryError::NonFinite("the fit's Jacobian at the solution");
    let jac = lsq::jacobian(&y, at).ok_or_else(undefined)?;
    let cov = lsq::covariance(&jac, solved_residuals, prior_sigma.powi(2))?;
    let solved = mirror_cameras(rig, plane);
    let cameras = propagate_to_cameras(
        &cov,
        &[0.0, 0.0, plane.distance],
        &[1e-6, 1e-6, 1e-6 * (1.0 + plane.distance.abs())],
        |p| {
            let moved = chart_here.plane(p).ok()?;
            Some(chart(&solved, &mirror_cameras(rig, &moved)))
        },
    )
    .ok_or_else(undefined)?;
    let mut out = Uncertainty::from_cameras(cameras, cov.residual_variance);
    out.cameras_stated = !cov.undetermined.iter().any(|&i| i < 3);
    if let (Some(a), Some(b)) = (cov.sigma(0), cov.sigma(1)) {
        out.plane_angle_deg = Some(a.hypot(b).to_degrees());
    }
    out.plane_distance_mm = cov.sigma(2);
    if offsets.is_some() {
        // Revolute offsets in degrees; a prismatic joint's stays in mm.
        let kinds = rig.arm.as_ref().map(geometry::Arm::joint_kinds);
        out.joint_offsets_deg = Some(
            (0..dof)
                .map(|j| {
                    let prismatic = kinds.as_ref().and_then(|k| k.get(j))
                        == Some(&geometry::JointKind::Prismatic);
                    cov.sigma(3 + j)
                        .map(|v| if prismatic { v } else { v.to_degrees() })
                })
                .collect(),
        );
    }
    let joint_names = rig
        .arm
        .as_ref()
        .map(geometry::Arm::joint_names)
        .unwrap_or_default();
    out.undetermined = cov
        .undetermined
        .iter()
        .map(|&i| match i {
            0 | 1 => "the mirror's tilt".to_string(),
            2 => "the mirror's distance".to_string(),
            j => format!(
                "the encoder offset of {}",
                joint_names
                    .get(j - 3)
                    .map_or_else(|| format!("joint {}", j - 2), Clone::clone)
            ),
        })
        .collect();
    out.undetermined.dedup();
    Ok(out)
}
