//! The paper's method, one camera at a time (Hart & Scassellati 2012).

use geometry::{Camera, GeometryError, Rig, Sample, lsq};
use nalgebra::{DVector, Rotation3, Vector3};

use super::uncertainty::{CameraCovariance, Uncertainty, perturb_camera};
use super::{CalibrateError, Calibration, Method, Observation, midplane, prepare, rms_px};

/// The paper's initial mirror cameras (Eqs 6-12) for both cameras.
///
/// What we find (see the README): the plane and the optical axis are exact
/// on noiseless data, but the minimal rotation from the canonical z-axis
/// fixes the roll about the axis 180 degrees away from the true one, since
/// the true mirror camera's rotation is a half-turn about the mirror normal.
pub fn initial_estimate(rig: &Rig, samples: &[Sample]) -> Result<[Camera; 2], CalibrateError> {
    let obs = prepare(rig, samples, super::Reading::default())?;
    Ok([
        initial_camera(&rig.cameras[0], &obs)?,
        initial_camera(&rig.cameras[1], &obs)?,
    ])
}

fn initial_camera(camera: &Camera, obs: &[Observation]) -> Result<Camera, GeometryError> {
    // Work in the camera's frame (camera at the origin, R = I).
    let pairs = obs.iter().map(|o| {
        (
            camera.to_camera(&o.model_point),
            camera.to_camera(&o.reflected_point),
        )
    });
    // Paper's orientation: <Π1, Π2, Π3> points from the J's to the Ĵ's.
    let plane = midplane(pairs)?.flipped();
    let (n, pi4) = (plane.normal.into_inner(), plane.distance);
    // Eq 10: the mirror camera's centre.
    let center = -2.0 * pi4 * n;
    // Eq 11: L, where the camera's z-axis meets the plane.
    if n.z.abs() < 1e-9 {
        return Err(GeometryError::Degenerate(
            "the mirror plane is parallel to the camera's optical axis".into(),
        ));
    }
    let l = Vector3::new(0.0, 0.0, -pi4 / n.z);
    // Eq 12: the mirror camera's z-axis, looking away from the mirror.
    let z_axis = center - l;
    let rotation = Rotation3::rotation_between(&Vector3::z(), &z_axis)
        .unwrap_or_else(|| Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI));
    // R̂ is the transpose of the rotation taking the canonical z-axis to Ẑ.
    let mirror_from_camera = rotation.matrix().transpose();
    Ok(Camera::new(
        camera.intrinsics,
        mirror_from_camera * camera.camera_from_world,
        camera.center + camera.camera_from_world.transpose() * center,
    ))
}

/// The residuals of camera `k`: the model points projected through `cam`
/// minus the detections.
fn residuals(cam: &Camera, obs: &[Observation], k: usize) -> Option<DVector<f64>> {
    let mut r = DVector::zeros(2 * obs.len());
    for (i, o) in obs.iter().enumerate() {
        let d = cam.project(&o.model_point).ok()? - o.pixels[k];
        r[2 * i] = d.x;
        r[2 * i + 1] = d.y;
    }
    Some(r)
}

/// A refined mirror camera, its residuals and its covariance in the
/// uncertainty chart (rotation vector, centre shift).
struct Refined {
    camera: Camera,
    residuals: DVector<f64>,
    /// Its covariance, or why none could be formed.
    covariance: Result<lsq::Covariance, GeometryError>,
}

/// Eq 13: 6-DOF refinement of one mirror camera on its reprojection error.
fn refine(
    start: &Camera,
    obs: &[Observation],
    k: usize,
    prior_sigma: Option<f64>,
) -> Result<Refined, GeometryError> {
    let camera_at = |x: &DVector<f64>| {
        let turn = Rotation3::new(Vector3::new(x[0], x[1], x[2]));
        Camera::new(
            start.intrinsics,
            turn.matrix() * start.camera_from_world,
            Vector3::new(x[3], x[4], x[5]),
        )
    };
    let x0 = DVector::from_vec(vec![
        0.0,
        0.0,
        0.0,
        start.center.x,
        start.center.y,
        start.center.z,
    ]);
    let (x, _) = lsq::minimize(x0, |x| residuals(&camera_at(x), obs, k))?;
    let camera = camera_at(&x);
    let undefined = || GeometryError::NonFinite("paper refinement residuals");
    let r = residuals(&camera, obs, k).ok_or_else(undefined)?;
    // The covariance in a chart centred on the solution.
    let at = |d: &DVector<f64>| residuals(&perturb_camera(&camera, d.as_slice()), obs, k);
    let covariance = if let Some(prior_sigma) = prior_sigma {
        lsq::jacobian(&DVector::zeros(6), at)
            .ok_or_else(undefined)
            .and_then(|jac| lsq::covariance(&jac, &r, prior_sigma.powi(2)))
    } else {
        Err(GeometryError::Degenerate("not asked for".into()))
    };
    Ok(Refined {
        camera,
        covariance,
        residuals: r,
    })
}

pub(super) fn calibrate(
    rig: &Rig,
    obs: &[Observation],
    prior_sigma: Option<f64>,
) -> Result<Calibration, CalibrateError> {
    let initial = [
        initial_camera(&rig.cameras[0], obs)?,
        initial_camera(&rig.cameras[1], obs)?,
    ];
    let left = refine(&initial[0], obs, 0, prior_sigma)?;
    let right = refine(&initial[1], obs, 1, prior_sigma)?;
    let uncertainty = match (&left.covariance, &right.covariance) {
        (Ok(l), Ok(r)) => uncertainty(rig, l, r),
        (Err(e), _) | (_, Err(e)) => Uncertainty::not_stated(&e.to_string()),
    };
    let all = DVector::from_iterator(
        left.residuals.len() + right.residuals.len(),
        left.residuals.iter().chain(right.residuals.iter()).copied(),
    );
    Ok(Calibration {
        method: Method::Paper,
        plane: None,
        mirror_cameras: [left.camera, right.camera],
        joint_offsets: None,
        initial_cameras: initial,
        train_rms_px: rms_px(&all),
        samples: obs.len(),
        direct_samples: 0,
        placements: vec![super::PlacementFit {
            plane: None,
            mirror_cameras: [left.camera, right.camera],
            samples: obs.len(),
        }],
        world_from_base: None,
        tool: None,
        parameters: 12,
        uncertainty,
        rejected: Vec::new(),
        fit: super::Fit::NotJudged,
    })
}

/// The two independent fits' covariances as one block-diagonal one, with
/// the pooled residual variance for the summary.
fn uncertainty(rig: &Rig, left: &lsq::Covariance, right: &lsq::Covariance) -> Uncertainty {
    let mut cameras = CameraCovariance::zeros();
    for (k, fit) in [left, right].into_iter().enumerate() {
        for i in 0..6 {
            for j in 0..6 {
                cameras[(6 * k + i, 6 * k + j)] = fit.matrix[(i, j)];
            }
        }
    }
    let variance = 0.5 * (left.residual_variance + right.residual_variance);
    let mut out = Uncertainty::from_cameras(cameras, variance);
    for (fit, name) in [left, right].into_iter().zip(&rig.names) {
        if !fit.undetermined.is_empty() {
            out.undetermined
                .push(format!("the {name} mirror camera's pose"));
            out.cameras_stated = false;
        }
    }
    out
}
