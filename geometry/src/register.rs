//! Closed-form rigid registration of point pairs (Umeyama 1991, without
//! scale): the baseline a user would reach for to place an arm's base from
//! points seen by the cameras and the same points from the arm's model.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::GeometryError;

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
}
