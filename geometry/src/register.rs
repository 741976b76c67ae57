//! Closed-form rigid registration of point pairs (Umeyama 1991, without
//! scale): the baseline a user would reach for to place an arm's base from
//! points seen by the cameras and the same points from the arm's model;
//! and a knocked camera's turn found again from points it sees.

use nalgebra::{
    DVector, Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3,
};

use crate::{Camera, GeometryError, lsq};

/// The rigid transform `T` minimising `sum |to_i - T from_i|^2`.
///
/// Fails for fewer than three pairs, or pairs whose `from` points lie on a
/// line (the rotation about it is not determined).
pub fn rigid(from: &[Vector3<f64>], to: &[Vector3<f64>]) -> Result<Isometry3<f64>, GeometryError> {
    if from.len() != to.len() || from.len() < 3 {
        return Err(GeometryError::Degenerate(format!(
            "rigid registration needs at least 3 point pairs, found {} and {}",
            from.len(),
            to.len()
        )));
    }
    let n = from.len() as f64;
    let mean_from = from.iter().sum::<Vector3<f64>>() / n;
    let mean_to = to.iter().sum::<Vector3<f64>>() / n;
    let cross: Matrix3<f64> = from
        .iter()
        .zip(to)
        .map(|(f, t)| (t - mean_to) * (f - mean_from).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let svd = cross.svd(true, true);
    let (u, v_t) = svd
        .u
        .zip(svd.v_t)
        .ok_or(GeometryError::NonFinite("registration decomposition"))?;
    let mut singular = svd.singular_values;
    singular.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if singular[1] <= 1e-9 * singular[0].max(f64::MIN_POSITIVE) {
        return Err(GeometryError::Degenerate(
            "the points lie on a line: the rotation about it is not determined".into(),
        ));
    }
    // A reflection is turned into the nearest rotation (Umeyama's S).
    let mut s = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let rotation = Rotation3::from_matrix_unchecked(u * s * v_t);
    let translation = mean_to - rotation * mean_from;
    Ok(Isometry3::from_parts(
        Translation3::from(translation),
        UnitQuaternion::from_rotation_matrix(&rotation),
    ))
}

/// A camera's turn found again from points it sees: the rotation vector
/// `w` (rad, about the camera's own axes, as [`Camera::turned`]) and its
/// 1-sigma, deg.
#[derive(Debug, Clone, PartialEq)]
pub struct Turn {
    /// The camera as found: `camera` turned by `w`.
    pub camera: Camera,
    /// The turn, rad.
    pub w: Vector3<f64>,
    /// The 1-sigma of the turn about each of the camera's axes, deg: x
    /// (tilt), y (pan), z (about the optical axis, which points clustered
    /// in the image determine least).
    pub sigma_deg: [f64; 3],
    /// The turn's covariance about the camera's axes, rad^2 (`sigma_deg`
    /// its diagonal's roots).
    pub covariance: Matrix3<f64>,
    /// RMS reprojection error after the turn, px.
    pub rms_px: f64,
}

/// How `camera`, knocked, is turned now: the rotation about its own centre
/// that best reprojects `points` (world, mm) onto `pixels` (least squares,
/// from no turn). Only the turn is found: a knock turns a camera's view
/// far more than it moves its centre, and from a few points a turn and a
/// shift of the centre are nearly the same (a 1 mm shift at 400 mm is
/// 0.14 deg); what shift there is shows as the turn that best explains it
/// at the points' distance. The covariance is scaled by the residual
/// variance, but not below `pixel_sigma`.
///
/// Fails for fewer than three points, or points the camera cannot see.
pub fn camera_turn(
    camera: &Camera,
    points: &[Vector3<f64>],
    pixels: &[Vector2<f64>],
    pixel_sigma: f64,
) -> Result<Turn, GeometryError> {
    camera_turn_weighted(camera, points, pixels, &vec![pixel_sigma; points.len()])
}

/// [`camera_turn`] with each point's own pixel sigma (per coordinate):
/// each point weighs by its inverse variance, and the covariance is scaled
/// by the weighted residuals' variance, but not below what the sigmas
/// state.
pub fn camera_turn_weighted(
    camera: &Camera,
    points: &[Vector3<f64>],
    pixels: &[Vector2<f64>],
    pixel_sigmas: &[f64],
) -> Result<Turn, GeometryError> {
    if points.len() != pixels.len() || points.len() != pixel_sigmas.len() || points.len() < 3 {
        return Err(GeometryError::Degenerate(format!(
            "a camera's turn needs at least 3 points seen, found {} points, {} pixels and {} sigmas",
            points.len(),
            pixels.len(),
            pixel_sigmas.len()
        )));
    }
    if pixel_sigmas.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(GeometryError::NonFinite("a point's pixel sigma"));
    }
    let pixel_errors = |x: &DVector<f64>| -> Option<DVector<f64>> {
        let turned = camera.turned(&Vector3::new(x[0], x[1], x[2]));
        let mut r = DVector::zeros(2 * points.len());
        for (i, (p, px)) in points.iter().zip(pixels).enumerate() {
            let e = turned.project(p).ok()? - px;
            r[2 * i] = e.x;
            r[2 * i + 1] = e.y;
        }
        Some(r)
    };
    let residuals = |x: &DVector<f64>| -> Option<DVector<f64>> {
        let mut r = pixel_errors(x)?;
        for (i, s) in pixel_sigmas.iter().enumerate() {
            r[2 * i] /= s;
            r[2 * i + 1] /= s;
        }
        Some(r)
    };
    let (x, _) = lsq::minimize(DVector::zeros(3), residuals)?;
    let r = residuals(&x).ok_or(GeometryError::NonFinite("camera turn residuals"))?;
    let jacobian =
        lsq::jacobian(&x, residuals).ok_or(GeometryError::NonFinite("camera turn Jacobian"))?;
    let mut covariance = lsq::covariance(&jacobian, &r, 1.0)?;
    if covariance.residual_variance <= 0.0 {
        // A perfect fit says nothing of the noise: the stated noise does.
        let stated = DVector::from_element(r.len(), 1.0);
        covariance = lsq::covariance(&jacobian, &stated, 1.0)?;
    }
    if !covariance.undetermined.is_empty() {
        return Err(GeometryError::Degenerate(
            "the points do not determine the camera's turn (too few, or on one ray)".into(),
        ));
    }
    // Not more confident than the detections' stated noise allows.
    let scale = (1.0 / covariance.residual_variance).max(1.0);
    let w = Vector3::new(x[0], x[1], x[2]);
    let covariance = covariance.matrix.fixed_view::<3, 3>(0, 0) * scale;
    let errors = pixel_errors(&x).ok_or(GeometryError::NonFinite("camera turn residuals"))?;
    Ok(Turn {
        camera: camera.turned(&w),
        w,
        sigma_deg: [0, 1, 2].map(|i| covariance[(i, i)].sqrt().to_degrees()),
        covariance,
        rms_px: (errors.norm_squared() / points.len() as f64).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_known_transform_and_refuses_a_line() {
        let truth = Isometry3::new(
            Vector3::new(120.0, -40.0, 300.0),
            Vector3::new(0.3, -1.1, 0.4),
        );
        let from: Vec<Vector3<f64>> = (0..12)
            .map(|i| {
                let t = i as f64;
                Vector3::new(50.0 * t.sin(), 80.0 * (0.7 * t).cos(), 10.0 * t)
            })
            .collect();
        let to: Vec<Vector3<f64>> = from
            .iter()
            .map(|p| truth.transform_vector(p) + truth.translation.vector)
            .collect();
        let found = rigid(&from, &to).unwrap();
        assert!((found.translation.vector - truth.translation.vector).norm() < 1e-9);
        assert!(found.rotation.angle_to(&truth.rotation) < 1e-12);
        let line: Vec<Vector3<f64>> = (0..5).map(|i| Vector3::x() * i as f64).collect();
        assert!(rigid(&line, &line).is_err());
    }

    #[test]
    fn finds_a_knocked_cameras_turn_from_ten_points() {
        let camera = Camera::new(
            crate::Intrinsics::ideal(640, 480, 520.0),
            Matrix3::identity(),
            Vector3::zeros(),
        );
        let truth = Vector3::new(0.001, 0.3f64.to_radians(), -0.002);
        let knocked = camera.turned(&truth);
        let points: Vec<Vector3<f64>> = (0..10)
            .map(|i| {
                let t = i as f64;
                Vector3::new(120.0 * t.sin(), 80.0 * (1.3 * t).cos(), 350.0 + 10.0 * t)
            })
            .collect();
        // 0.2 px of noise, in a fixed pattern.
        let pixels: Vec<Vector2<f64>> = points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let n = 0.2 * Vector2::new((7.0 * i as f64).sin(), (11.0 * i as f64).cos());
                knocked.project(p).unwrap() + n
            })
            .collect();
        let found = camera_turn(&camera, &points, &pixels, 0.2).unwrap();
        let error = (Rotation3::new(found.w) * Rotation3::new(truth).inverse()).scaled_axis();
        for i in 0..3 {
            let (e, sigma) = (error[i].to_degrees().abs(), found.sigma_deg[i]);
            assert!(e < 3.0 * sigma, "axis {i}: {e} deg, sigma {sigma}");
            assert!(sigma < 0.05, "axis {i}: sigma {sigma}");
        }
        assert!(camera_turn(&camera, &points[..2], &pixels[..2], 0.2).is_err());
        // Without noise the stated noise still bounds the sigmas.
        let exact: Vec<Vector2<f64>> = points.iter().map(|p| knocked.project(p).unwrap()).collect();
        let found = camera_turn(&camera, &points, &exact, 0.2).unwrap();
        assert!(
            found.sigma_deg.iter().all(|s| s.is_finite() && *s > 0.0),
            "{:?}",
            found.sigma_deg
        );
    }
}
