//! Pinhole camera with OpenCV's lens distortion ([`Distortion`]).
//!
//! Normalised coordinates `(x, y) = (X/Z, Y/Z)` are distorted to
//! `(x_d, y_d)`, then `u = fx x_d + skew y_d + cx`, `v = fy y_d + cy`. The rotation
//! `camera_from_world` may be improper (det -1, a raw mirror camera); depth may
//! be negative (a proper mirror camera looks away from the mirror). Only a
//! point with zero depth cannot be projected.

use nalgebra::{Matrix2, Matrix2x3, Matrix3, Matrix3x4, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::{Distortion, GeometryError};

/// Smallest |depth| (mm) a point may have and still be projected.
const MIN_ABS_DEPTH: f64 = 1e-9;

/// Intrinsic parameters, shared by a real camera and its mirror cameras.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along u, pixels.
    pub fx: f64,
    /// Focal length along v, pixels.
    pub fy: f64,
    /// Skew (gamma), pixels.
    pub skew: f64,
    /// Principal point u.
    pub cx: f64,
    /// Principal point v.
    pub cy: f64,
    /// Lens distortion.
    pub dist: Distortion,
}

impl Intrinsics {
    /// Square pixels, no skew, centred principal point, no distortion.
    pub fn ideal(width: u32, height: u32, focal: f64) -> Self {
        Self {
            width,
            height,
            fx: focal,
            fy: focal,
            skew: 0.0,
            cx: f64::from(width) / 2.0,
            cy: f64::from(height) / 2.0,
            dist: Distortion::default(),
        }
    }

    /// The calibration matrix `K`.
    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(
            self.fx, self.skew, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0,
        )
    }

    /// Distorted normalised coordinates to pixels (`K` applied).
    fn apply_k(&self, d: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(
            self.fx * d.x + self.skew * d.y + self.cx,
            self.fy * d.y + self.cy,
        )
    }

    /// Normalised undistorted coordinates to distorted pixels.
    pub fn distort_to_pixel(&self, xy: &Vector2<f64>) -> Vector2<f64> {
        self.apply_k(&self.dist.distort(xy))
    }

    /// `d pixel / d xy` at normalised undistorted `xy`.
    pub fn pixel_jacobian(&self, xy: &Vector2<f64>) -> Matrix2<f64> {
        Matrix2::new(self.fx, self.skew, 0.0, self.fy) * self.dist.jacobian(xy)
    }

    /// Distorted pixels to normalised undistorted coordinates (Newton's
    /// method on the distortion model; converges to ~1e-12 in a few steps).
    pub fn undistort_pixel(&self, px: &Vector2<f64>) -> Result<Vector2<f64>, GeometryError> {
        if !(px.x.is_finite() && px.y.is_finite()) {
            return Err(GeometryError::NonFinite("pixel"));
        }
        let yd = (px.y - self.cy) / self.fy;
        let xd = (px.x - self.cx - self.skew * yd) / self.fx;
        self.dist
            .undistort(&Vector2::new(xd, yd))
            .ok_or(GeometryError::UndistortDiverged { u: px.x, v: px.y })
    }

    /// The image of a planar marker's centre from its four detected
    /// corners (in order round the marker): where its diagonals cross once
    /// the lens's distortion is undone, distorted back. The diagonals of the
    /// raw corners cross elsewhere under distortion, by a pixel for a large
    /// marker towards the edge of a wide lens.
    pub fn marker_center(
        &self,
        corners: &[Vector2<f64>; 4],
    ) -> Result<Vector2<f64>, GeometryError> {
        let c = corners
            .iter()
            .map(|p| self.undistort_pixel(p))
            .collect::<Result<Vec<_>, _>>()?;
        let (r, s) = (c[2] - c[0], c[3] - c[1]);
        let denom = r.x * s.y - r.y * s.x;
        if denom.abs() < 1e-15 {
            return Err(GeometryError::Degenerate(
                "the marker's corners are collinear".into(),
            ));
        }
        let t = ((c[1] - c[0]).x * s.y - (c[1] - c[0]).y * s.x) / denom;
        Ok(self.distort_to_pixel(&(c[0] + r * t)))
    }

    /// `d xy / d pixel` of [`Self::undistort_pixel`] at `px`: the inverse of
    /// [`Self::pixel_jacobian`] at the undistorted point.
    pub fn undistort_jacobian(&self, px: &Vector2<f64>) -> Result<Matrix2<f64>, GeometryError> {
        let xy = self.undistort_pixel(px)?;
        self.pixel_jacobian(&xy)
            .try_inverse()
            .ok_or(GeometryError::UndistortDiverged { u: px.x, v: px.y })
    }

    /// Whether a pixel lies inside the image with `margin` pixels to spare.
    pub fn contains(&self, px: &Vector2<f64>, margin: f64) -> bool {
        px.x >= margin
            && px.y >= margin
            && px.x <= f64::from(self.width) - margin
            && px.y <= f64::from(self.height) - margin
    }
}

/// A calibrated camera `P = K [R | -R C]` with lens distortion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Intrinsic parameters.
    pub intrinsics: Intrinsics,
    /// `R`: rotation from world to camera coordinates (det may be -1 for a raw mirror camera).
    pub camera_from_world: Matrix3<f64>,
    /// `C`: camera centre in world coordinates.
    pub center: Vector3<f64>,
}

impl Camera {
    /// A camera from its parts.
    pub fn new(
        intrinsics: Intrinsics,
        camera_from_world: Matrix3<f64>,
        center: Vector3<f64>,
    ) -> Self {
        Self {
            intrinsics,
            camera_from_world,
            center,
        }
    }

    /// This camera turned by the rotation vector `w` (rad) about its own
    /// axes (x right, y down, z forward), its centre kept: `R' = exp(w) R`.
    pub fn turned(&self, w: &Vector3<f64>) -> Self {
        Self {
            camera_from_world: nalgebra::Rotation3::new(*w).matrix() * self.camera_from_world,
            ..*self
        }
    }

    /// World point to camera coordinates `R (X - C)`.
    pub fn to_camera(&self, world: &Vector3<f64>) -> Vector3<f64> {
        self.camera_from_world * (world - self.center)
    }

    /// Normalised (undistorted) image coordinates of a world point.
    pub fn normalized(&self, world: &Vector3<f64>) -> Result<Vector2<f64>, GeometryError> {
        let pc = self.to_camera(world);
        // Also rejects a NaN depth.
        if pc.z.abs().partial_cmp(&MIN_ABS_DEPTH) != Some(std::cmp::Ordering::Greater) {
            return Err(GeometryError::ZeroDepth);
        }
        Ok(Vector2::new(pc.x / pc.z, pc.y / pc.z))
    }

    /// The unit direction, in the world, of the ray through pixel `px`
    /// (distorted): the inverse of [`Camera::project`] up to depth.
    pub fn ray(&self, px: &Vector2<f64>) -> Result<Vector3<f64>, GeometryError> {
        let xy = self.intrinsics.undistort_pixel(px)?;
        Ok((self.camera_from_world.transpose() * Vector3::new(xy.x, xy.y, 1.0)).normalize())
    }

    /// Distorted pixel coordinates of a world point.
    pub fn project(&self, world: &Vector3<f64>) -> Result<Vector2<f64>, GeometryError> {
        Ok(self.intrinsics.distort_to_pixel(&self.normalized(world)?))
    }

    /// The camera's frame in the world as a rigid transform: `R^T` and `C`.
    /// An improper `R` (a raw mirror camera) is negated first: `-R` gives
    /// the same projection and is a rotation.
    pub fn world_from_camera(&self) -> nalgebra::Isometry3<f64> {
        let r = if self.camera_from_world.determinant() < 0.0 {
            -self.camera_from_world
        } else {
            self.camera_from_world
        };
        nalgebra::Isometry3::from_parts(
            nalgebra::Translation3::from(self.center),
            nalgebra::UnitQuaternion::from_matrix(&r.transpose()),
        )
    }

    /// `d pixel / d world` of [`Self::project`] at a world point.
    pub fn project_jacobian(&self, world: &Vector3<f64>) -> Result<Matrix2x3<f64>, GeometryError> {
        let pc = self.to_camera(world);
        let xy = self.normalized(world)?;
        let z = pc.z;
        // d(x, y)/d(camera point), then through R.
        let dn = Matrix2x3::new(1.0 / z, 0.0, -xy.x / z, 0.0, 1.0 / z, -xy.y / z);
        Ok(self.intrinsics.pixel_jacobian(&xy) * dn * self.camera_from_world)
    }

    /// Depth of a world point along the optical axis (negative behind the camera).
    pub fn depth(&self, world: &Vector3<f64>) -> f64 {
        self.to_camera(world).z
    }

    /// The normalised projection matrix `[R | -R C]` (no `K`, no distortion).
    pub fn normalized_projection(&self) -> Matrix3x4<f64> {
        let mut p = Matrix3x4::zeros();
        p.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&self.camera_from_world);
        p.set_column(3, &(-self.camera_from_world * self.center));
        p
    }

    /// The full linear projection matrix `K [R | -R C]` (distortion not included).
    pub fn projection_matrix(&self) -> Matrix3x4<f64> {
        self.intrinsics.k() * self.normalized_projection()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn nico_like() -> Intrinsics {
        Intrinsics {
            width: 640,
            height: 480,
            fx: 552.0,
            fy: 548.0,
            skew: 0.4,
            cx: 318.0,
            cy: 243.0,
            dist: Distortion::from_opencv(&[-0.22, 0.06, 0.0011, -0.0009, -0.01]).unwrap(),
        }
    }

    #[test]
    fn a_markers_centre_is_found_through_the_lens_model() {
        // A 90 mm card 400 mm away, off to the side and tilted, as a
        // direct view of the arm's marker is.
        let cam = Camera::new(nico_like(), Matrix3::identity(), Vector3::zeros());
        let center = Vector3::new(-160.0, 90.0, 400.0);
        let turn = nalgebra::Rotation3::from_euler_angles(0.4, -0.5, 0.2);
        let corners: [Vector2<f64>; 4] =
            [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(x, y)| {
                cam.project(&(center + turn * Vector3::new(45.0 * x, 45.0 * y, 0.0)))
                    .unwrap()
            });
        let truth = cam.project(&center).unwrap();
        let found = cam.intrinsics.marker_center(&corners).unwrap();
        assert!((found - truth).norm() < 1e-6, "{found} vs {truth}");
        // The raw corners' diagonals cross visibly elsewhere.
        let (a, b) = (corners[2] - corners[0], corners[3] - corners[1]);
        let t = ((corners[1] - corners[0]).x * b.y - (corners[1] - corners[0]).y * b.x)
            / (a.x * b.y - a.y * b.x);
        let naive = corners[0] + a * t;
        assert!((naive - truth).norm() > 0.3, "naive {naive} vs {truth}");
    }

    fn pixel_in_image() -> impl Strategy<Value = Vector2<f64>> {
        (0.0..640.0f64, 0.0..480.0f64).prop_map(|(u, v)| Vector2::new(u, v))
    }

    proptest! {
        #[test]
        fn undistort_then_distort_round_trips(px in pixel_in_image()) {
            let k = nico_like();
            let xy = k.undistort_pixel(&px).unwrap();
            let back = k.distort_to_pixel(&xy);
            prop_assert!((back - px).norm() < 1e-6, "round trip error {}", (back - px).norm());
        }

        #[test]
        fn project_then_undistort_recovers_the_ray(
            x in -300.0..300.0f64, y in -200.0..200.0f64, z in 300.0..2000.0f64
        ) {
            let cam = Camera::new(nico_like(), Matrix3::identity(), Vector3::zeros());
            let p = Vector3::new(x, y, z);
            let px = cam.project(&p).unwrap();
            prop_assume!(cam.intrinsics.contains(&px, 0.0));
            let xy = cam.intrinsics.undistort_pixel(&px).unwrap();
            prop_assert!((xy - Vector2::new(x / z, y / z)).norm() < 1e-9);
            prop_assert!((cam.ray(&px).unwrap() - p.normalize()).norm() < 1e-9);
        }
    }

    #[test]
    fn world_from_camera_inverts_the_pose_also_for_an_improper_rotation() {
        let r = *nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 1.1).matrix();
        let c = Vector3::new(10.0, -20.0, 30.0);
        let p = Vector3::new(50.0, 40.0, 600.0);
        for rot in [r, r * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0))] {
            let cam = Camera::new(nico_like(), rot, c);
            let pose = cam.world_from_camera();
            let local = pose.inverse_transform_point(&p.into()).coords;
            // Same ray: equal up to the sign of the homogeneous scale.
            let expect = cam.to_camera(&p);
            let sign = if rot.determinant() < 0.0 { -1.0 } else { 1.0 };
            assert!((local - expect * sign).norm() < 1e-9, "{local} vs {expect}");
        }
    }

    #[test]
    fn derivatives_match_central_differences() {
        let r = *nalgebra::Rotation3::from_euler_angles(0.1, -0.2, 0.05).matrix();
        let cam = Camera::new(nico_like(), r, Vector3::new(5.0, -3.0, 2.0));
        let h = 1e-4;
        for p in [
            Vector3::new(40.0, -30.0, 500.0),
            Vector3::new(-150.0, 90.0, 420.0),
        ] {
            let j = cam.project_jacobian(&p).unwrap();
            for c in 0..3 {
                let mut e = Vector3::zeros();
                e[c] = h;
                let numeric =
                    (cam.project(&(p + e)).unwrap() - cam.project(&(p - e)).unwrap()) / (2.0 * h);
                assert!((j.column(c) - numeric).norm() < 1e-6, "{j} vs {numeric}");
            }
            let px = cam.project(&p).unwrap();
            let ju = cam.intrinsics.undistort_jacobian(&px).unwrap();
            for c in 0..2 {
                let mut e = Vector2::zeros();
                e[c] = 1e-3;
                let k = &cam.intrinsics;
                let numeric = (k.undistort_pixel(&(px + e)).unwrap()
                    - k.undistort_pixel(&(px - e)).unwrap())
                    / 2e-3;
                assert!((ju.column(c) - numeric).norm() < 1e-9, "{ju} vs {numeric}");
            }
        }
    }

    #[test]
    fn ideal_camera_projects_like_k_times_point() {
        let cam = Camera::new(
            Intrinsics::ideal(640, 480, 500.0),
            Matrix3::identity(),
            Vector3::zeros(),
        );
        let px = cam.project(&Vector3::new(10.0, -20.0, 100.0)).unwrap();
        assert!((px - Vector2::new(320.0 + 50.0, 240.0 - 100.0)).norm() < 1e-12);
    }

    #[test]
    fn zero_depth_is_an_error_not_a_nan() {
        let cam = Camera::new(nico_like(), Matrix3::identity(), Vector3::zeros());
        assert_eq!(
            cam.project(&Vector3::new(1.0, 2.0, 0.0)),
            Err(GeometryError::ZeroDepth)
        );
        assert!(
            cam.intrinsics
                .undistort_pixel(&Vector2::new(f64::NAN, 1.0))
                .is_err()
        );
    }
}
