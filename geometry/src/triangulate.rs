//! Stereo triangulation.
//!
//! Method: the midpoint of the two rays' closest approach gives a start;
//! Levenberg-Marquardt then minimises the pixel reprojection error in both
//! cameras with distortion (the maximum-likelihood point under isotropic
//! Gaussian pixel noise). Neither step tests the sign of the depth, so it
//! works for mirror cameras, whose points lie at negative depth.
//!
//! Why not start from the linear DLT ([`triangulate_dlt`], kept for
//! comparison with OpenCV): it is not invariant to the mirror's reflection
//! (a non-orthogonal homogeneous transform), and through mirror cameras, with
//! noise, it can land on the wrong side of the cameras, from where the
//! refinement runs off to infinity. The midpoint commutes with reflections.

use nalgebra::{DVector, Matrix4, Vector2, Vector3};

use crate::{Camera, GeometryError, lsq};

/// Linear triangulation from normalised coordinates and the cameras' `[R | -R C]`.
pub fn triangulate_dlt(
    cameras: [&Camera; 2],
    pixels: [Vector2<f64>; 2],
) -> Result<Vector3<f64>, GeometryError> {
    let mut a = Matrix4::zeros();
    for (k, (cam, px)) in cameras.iter().zip(pixels.iter()).enumerate() {
        let xy = cam.intrinsics.undistort_pixel(px)?;
        let p = cam.normalized_projection();
        a.set_row(2 * k, &(p.row(2) * xy.x - p.row(0)));
        a.set_row(2 * k + 1, &(p.row(2) * xy.y - p.row(1)));
    }
    // Scale rows so each equation has unit norm (conditioning).
    for r in 0..4 {
        let n = a.row(r).norm();
        if n > 0.0 {
            a.set_row(r, &(a.row(r) / n));
        }
    }
    let svd = a.svd(false, true);
    let v_t = svd
        .v_t
        .ok_or(GeometryError::Degenerate("SVD failed".into()))?;
    // nalgebra does not sort singular values; take the smallest.
    let (imin, _) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|x, y| x.1.total_cmp(y.1))
        .ok_or(GeometryError::Degenerate("empty SVD".into()))?;
    let h = v_t.row(imin);
    if h[3].abs() < 1e-12 * h.norm() {
        return Err(GeometryError::Degenerate(
            "rays are parallel: the point is at infinity".into(),
        ));
    }
    let p = Vector3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]);
    if p.iter().all(|v| v.is_finite()) {
        Ok(p)
    } else {
        Err(GeometryError::NonFinite("triangulated point"))
    }
}

/// Pixel residuals of a point in both cameras (4 values).
fn reprojection(
    cameras: [&Camera; 2],
    pixels: &[Vector2<f64>; 2],
    p: &Vector3<f64>,
) -> Option<DVector<f64>> {
    let mut r = DVector::zeros(4);
    for k in 0..2 {
        let d = cameras[k].project(p).ok()? - pixels[k];
        r[2 * k] = d.x;
        r[2 * k + 1] = d.y;
    }
    Some(r)
}

/// The midpoint of the shortest segment between the two viewing rays
/// (taken as full lines, so the sign of the depth does not matter).
pub fn triangulate_midpoint(
    cameras: [&Camera; 2],
    pixels: [Vector2<f64>; 2],
) -> Result<Vector3<f64>, GeometryError> {
    let mut dirs = [Vector3::zeros(); 2];
    for k in 0..2 {
        dirs[k] = cameras[k].ray(&pixels[k])?;
    }
    let (c0, c1) = (cameras[0].center, cameras[1].center);
    let w = c0 - c1;
    let b = dirs[0].dot(&dirs[1]);
    let (d, e) = (dirs[0].dot(&w), dirs[1].dot(&w));
    let denom = 1.0 - b * b;
    if denom < 1e-14 {
        return Err(GeometryError::Degenerate(
            "rays are parallel: the point is at infinity".into(),
        ));
    }
    let t0 = (b * e - d) / denom;
    let t1 = (e - b * d) / denom;
    let p = 0.5 * ((c0 + dirs[0] * t0) + (c1 + dirs[1] * t1));
    if p.iter().all(|v| v.is_finite()) {
        Ok(p)
    } else {
        Err(GeometryError::NonFinite("triangulated point"))
    }
}

/// Triangulates a point seen at `pixels` (raw, distorted) by two cameras:
/// ray midpoint, then reprojection-error refinement.
pub fn triangulate(
    cameras: [&Camera; 2],
    pixels: [Vector2<f64>; 2],
) -> Result<Vector3<f64>, GeometryError> {
    let start = triangulate_midpoint(cameras, pixels)?;
    let (x, _) = lsq::minimize(DVector::from_column_slice(start.as_slice()), |x| {
        reprojection(cameras, &pixels, &Vector3::new(x[0], x[1], x[2]))
    })?;
    Ok(Vector3::new(x[0], x[1], x[2]))
}

/// Mean over both cameras of the pixel distance between a point's projection
/// and the detections: the paper's per-sample 2D error.
pub fn mean_reprojection_error(
    cameras: [&Camera; 2],
    pixels: [Vector2<f64>; 2],
    p: &Vector3<f64>,
) -> Result<f64, GeometryError> {
    let a = (cameras[0].project(p)? - pixels[0]).norm();
    let b = (cameras[1].project(p)? - pixels[1]).norm();
    Ok(0.5 * (a + b))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Intrinsics, Plane};
    use nalgebra::{Matrix3, Rotation3};
    use proptest::prelude::*;

    fn stereo() -> [Camera; 2] {
        let k = Intrinsics {
            dist: crate::Distortion::from_opencv(&[-0.2, 0.05, 0.001, -0.0008, 0.01]).unwrap(),
            skew: 0.3,
            ..Intrinsics::ideal(640, 480, 550.0)
        };
        let toe = |a: f64| *Rotation3::from_axis_angle(&Vector3::y_axis(), a).matrix();
        [
            Camera::new(k, toe(0.03), Vector3::new(-30.0, 0.0, 0.0)),
            Camera::new(k, toe(-0.03), Vector3::new(30.0, 0.0, 0.0)),
        ]
    }

    proptest! {
        #[test]
        fn exact_projections_triangulate_to_the_point(
            x in -150.0..150.0f64, y in -100.0..100.0f64, z in 250.0..1200.0f64
        ) {
            let cams = stereo();
            let p = Vector3::new(x, y, z);
            let px = [cams[0].project(&p).unwrap(), cams[1].project(&p).unwrap()];
            let got = triangulate([&cams[0], &cams[1]], px).unwrap();
            prop_assert!((got - p).norm() < 1e-6 * z, "{} vs {}", got, p);
        }

        #[test]
        fn mirror_cameras_triangulate_points_at_negative_depth(
            x in -100.0..100.0f64, y in -80.0..80.0f64, z in 150.0..350.0f64
        ) {
            let cams = stereo();
            let mirror = Plane::new(Vector3::new(0.15, -0.1, -1.0), 450.0).unwrap();
            let virt = [mirror.mirror_camera(&cams[0]), mirror.mirror_camera(&cams[1])];
            let p = Vector3::new(x, y, z);
            prop_assert!(virt[0].depth(&p) < 0.0);
            let px = [virt[0].project(&p).unwrap(), virt[1].project(&p).unwrap()];
            let got = triangulate([&virt[0], &virt[1]], px).unwrap();
            prop_assert!((got - p).norm() < 1e-6 * 1000.0, "{} vs {}", got, p);
        }
    }

    #[test]
    fn noisy_mirror_triangulation_is_the_reflection_of_the_real_one() {
        // Through the mirror cameras the best point is the reflection of the
        // best point through the real cameras; the DLT start broke this.
        let cams = stereo();
        let mirror = Plane::new(Vector3::new(0.1, 0.15, -1.0), 520.0).unwrap();
        let virt = [
            mirror.mirror_camera(&cams[0]),
            mirror.mirror_camera(&cams[1]),
        ];
        for i in 0..200 {
            let t = f64::from(i);
            let p = Vector3::new(
                150.0 * (0.37 * t).sin(),
                100.0 + 80.0 * (0.23 * t).cos(),
                150.0 + 100.0 * (0.11 * t).sin(),
            );
            let noise = |s: f64| Vector2::new((1.7 * s).sin(), (2.9 * s).cos()) * 3.0;
            let px = [
                virt[0].project(&p).unwrap() + noise(t),
                virt[1].project(&p).unwrap() + noise(t + 0.5),
            ];
            let real = triangulate([&cams[0], &cams[1]], px).unwrap();
            let through_mirror = triangulate([&virt[0], &virt[1]], px).unwrap();
            assert!(
                (mirror.reflect_point(&real) - through_mirror).norm() < 1e-6 * (1.0 + real.norm()),
                "{real} vs {through_mirror}"
            );
        }
    }

    #[test]
    fn parallel_rays_are_an_error() {
        let k = Intrinsics::ideal(640, 480, 500.0);
        let a = Camera::new(k, Matrix3::identity(), Vector3::zeros());
        let b = Camera::new(k, Matrix3::identity(), Vector3::new(60.0, 0.0, 0.0));
        let px = Vector2::new(320.0, 240.0);
        assert!(triangulate([&a, &b], [px, px]).is_err());
    }
}
