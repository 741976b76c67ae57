//! Planes `n . X + d = 0` (`|n| = 1`), reflections and mirror cameras.

use nalgebra::{Matrix3, Unit, Vector3};

use crate::{Camera, GeometryError};

/// An oriented plane `n . X + d = 0` with unit normal `n`.
///
/// For a mirror we orient `n` towards the reflecting side (the robot), so a
/// point in front of the mirror has positive signed distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: Unit<Vector3<f64>>,
    /// Offset `d`: the signed distance of the origin is `d`.
    pub distance: f64,
}

impl Plane {
    /// A plane from any non-zero normal and the offset for that normal
    /// (both are rescaled so the normal has unit length).
    pub fn new(normal: Vector3<f64>, distance: f64) -> Result<Self, GeometryError> {
        let len = normal.norm();
        if !(len.is_finite() && distance.is_finite()) {
            return Err(GeometryError::NonFinite("plane"));
        }
        if len < 1e-12 {
            return Err(GeometryError::Degenerate(
                "plane normal has zero length".into(),
            ));
        }
        Ok(Self {
            normal: Unit::new_unchecked(normal / len),
            distance: distance / len,
        })
    }

    /// The plane through `point` with normal `normal`.
    pub fn through(point: &Vector3<f64>, normal: Vector3<f64>) -> Result<Self, GeometryError> {
        let n = Self::new(normal, 0.0)?.normal;
        Self::new(n.into_inner(), -n.dot(point))
    }

    /// Signed distance of a point (positive on the side the normal points to).
    pub fn signed_distance(&self, p: &Vector3<f64>) -> f64 {
        self.normal.dot(p) + self.distance
    }

    /// Mirror image of a point: `X' = X - 2 (n . X + d) n`.
    pub fn reflect_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        p - self.normal.into_inner() * (2.0 * self.signed_distance(p))
    }

    /// The Householder matrix `S = I - 2 n n^T` (reflects directions).
    pub fn householder(&self) -> Matrix3<f64> {
        let n = self.normal.into_inner();
        Matrix3::identity() - n * n.transpose() * 2.0
    }

    /// The same plane with the normal flipped.
    pub fn flipped(&self) -> Self {
        Self {
            normal: -self.normal,
            distance: -self.distance,
        }
    }

    /// A frame on the plane: origin at the point closest to the world
    /// origin (`-d n`), z along the normal (towards the robot).
    pub fn world_from_plane(&self) -> nalgebra::Isometry3<f64> {
        let rotation = nalgebra::UnitQuaternion::rotation_between(&Vector3::z(), &self.normal)
            .unwrap_or_else(|| {
                // The normal is -z: any half turn about an axis in the xy plane.
                nalgebra::UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
            });
        nalgebra::Isometry3::from_parts(
            nalgebra::Translation3::from(-self.normal.into_inner() * self.distance),
            rotation,
        )
    }

    /// The exact mirror-perspective camera in its proper form: centre
    /// `C' = C - 2 (n . C + d) n`, rotation `-R S` (det +1). Scene points in
    /// front of the mirror have negative depth in it (the paper's camera
    /// "looking away from the mirror"); it projects them exactly where their
    /// reflections project through the real camera.
    pub fn mirror_camera(&self, camera: &Camera) -> Camera {
        Camera {
            intrinsics: camera.intrinsics,
            camera_from_world: -(camera.camera_from_world * self.householder()),
            center: self.reflect_point(&camera.center),
        }
    }

    /// The raw mirror camera `R S` (det -1); projects identically to
    /// [`Plane::mirror_camera`].
    pub fn mirror_camera_improper(&self, camera: &Camera) -> Camera {
        Camera {
            camera_from_world: camera.camera_from_world * self.householder(),
            ..self.mirror_camera(camera)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Intrinsics;
    use proptest::prelude::*;

    fn unit_vector() -> impl Strategy<Value = Vector3<f64>> {
        (-1.0..1.0f64, 0.0..std::f64::consts::TAU).prop_map(|(z, phi)| {
            let r = (1.0 - z * z).sqrt();
            Vector3::new(r * phi.cos(), r * phi.sin(), z)
        })
    }

    fn point() -> impl Strategy<Value = Vector3<f64>> {
        (-1000.0..1000.0f64, -1000.0..1000.0f64, -1000.0..1000.0f64)
            .prop_map(|(x, y, z)| Vector3::new(x, y, z))
    }

    fn plane() -> impl Strategy<Value = Plane> {
        (unit_vector(), -800.0..800.0f64).prop_map(|(n, d)| Plane::new(n, d).unwrap())
    }

    fn camera_rotation() -> impl Strategy<Value = Matrix3<f64>> {
        (unit_vector(), 0.0..std::f64::consts::PI).prop_map(|(axis, angle)| {
            *nalgebra::Rotation3::from_axis_angle(&Unit::new_normalize(axis), angle).matrix()
        })
    }

    proptest! {
        #[test]
        fn reflection_is_an_involution(p in point(), pl in plane()) {
            let twice = pl.reflect_point(&pl.reflect_point(&p));
            prop_assert!((twice - p).norm() < 1e-9);
            // and it keeps the point's distance to the plane, flipping its side
            prop_assert!((pl.signed_distance(&pl.reflect_point(&p)) + pl.signed_distance(&p)).abs() < 1e-9);
        }

        #[test]
        fn mirror_rotation_is_improper_and_its_negation_proper(
            pl in plane(), r in camera_rotation(), c in point(), p in point()
        ) {
            let cam = Camera::new(Intrinsics::ideal(640, 480, 500.0), r, c);
            let raw = pl.mirror_camera_improper(&cam);
            let proper = pl.mirror_camera(&cam);
            prop_assert!((raw.camera_from_world.determinant() + 1.0).abs() < 1e-9);
            prop_assert!((proper.camera_from_world.determinant() - 1.0).abs() < 1e-9);
            let orth = proper.camera_from_world * proper.camera_from_world.transpose();
            prop_assert!((orth - Matrix3::identity()).norm() < 1e-9);
            // Both forms project a point identically, and like the reflection through the real camera.
            prop_assume!(cam.depth(&pl.reflect_point(&p)).abs() > 1.0);
            let a = raw.project(&p).unwrap();
            let b = proper.project(&p).unwrap();
            let c2 = cam.project(&pl.reflect_point(&p)).unwrap();
            let scale = 1.0 + a.norm();
            prop_assert!((a - b).norm() < 1e-9 * scale);
            prop_assert!((a - c2).norm() < 1e-9 * scale);
            // Depth in the proper mirror camera is the negated depth of the reflection.
            prop_assert!((proper.depth(&p) + cam.depth(&pl.reflect_point(&p))).abs() < 1e-6);
        }
    }

    #[test]
    fn plane_new_rejects_zero_and_nan() {
        assert!(Plane::new(Vector3::zeros(), 1.0).is_err());
        assert!(Plane::new(Vector3::new(f64::NAN, 0.0, 1.0), 1.0).is_err());
    }
}
