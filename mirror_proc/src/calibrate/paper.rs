//! The paper's method, one camera at a time (Hart & Scassellati 2012).

use geometry::{Camera, GeometryError, Rig, Sample, lsq};
use nalgebra::{DVector, Rotation3, Vector3};

use super::{CalibrateError, Calibration, Method, Observation, midplane, prepare, rms_px};

/// The paper's initial mirror cameras (Eqs 6-12) for both cameras.
///
/// What we find (see the README): the plane and the optical axis are exact
/// on noiseless data, but the minimal rotation from the canonical z-axis
/// fixes the roll about the axis 180 degrees away from the true one, since
/// the true mirror camera's rotation is a half-turn about the mirror normal.
pub fn initial_estimate(rig: &Rig, samples: &[Sample]) -> Result<[Camera; 2], CalibrateError> {
    let obs = prepare(rig, samples, false)?;
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

/// Eq 13: 6-DOF refinement of one mirror camera on its reprojection error.
fn refine(
    start: &Camera,
    obs: &[Observation],
    k: usize,
) -> Result<(Camera, DVector<f64>), GeometryError> {
    let camera_at = |x: &DVector<f64>| {
        let turn = Rotation3::new(Vector3::new(x[0], x[1], x[2]));
        Camera::new(
            start.intrinsics,
            turn.matrix() * start.camera_from_world,
            Vector3::new(x[3], x[4], x[5]),
        )
    };
    let residuals = |x: &DVector<f64>| {
        let cam = camera_at(x);
        let mut r = DVector::zeros(2 * obs.len());
        for (i, o) in obs.iter().enumerate() {
            let d = cam.project(&o.model_point).ok()? - o.pixels[k];
            r[2 * i] = d.x;
            r[2 * i + 1] = d.y;
        }
        Some(r)
    };
    let x0 = DVector::from_vec(vec![
        0.0,
        0.0,
        0.0,
        start.center.x,
        start.center.y,
        start.center.z,
    ]);
    let (x, _) = lsq::minimize(x0, residuals)?;
    let r = residuals(&x).ok_or(GeometryError::NonFinite("paper refinement residuals"))?;
    Ok((camera_at(&x), r))
}

pub(super) fn calibrate(rig: &Rig, obs: &[Observation]) -> Result<Calibration, CalibrateError> {
    let initial = [
        initial_camera(&rig.cameras[0], obs)?,
        initial_camera(&rig.cameras[1], obs)?,
    ];
    let (left, r_left) = refine(&initial[0], obs, 0)?;
    let (right, r_right) = refine(&initial[1], obs, 1)?;
    let all = DVector::from_iterator(
        r_left.len() + r_right.len(),
        r_left.iter().chain(r_right.iter()).copied(),
    );
    Ok(Calibration {
        method: Method::Paper,
        plane: None,
        mirror_cameras: [left, right],
        joint_offsets: None,
        initial_cameras: initial,
        train_rms_px: rms_px(&all),
        samples: obs.len(),
    })
}
