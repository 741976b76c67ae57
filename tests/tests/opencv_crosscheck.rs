//! Our geometry against OpenCV's own functions on the same inputs:
//! `projectPoints` and `undistortPoints` (with two-term radial, 5-term
//! `plumb_bob` and 8-term rational distortion), and `triangulatePoints`.

use geometry::sim::nico_scene;
use geometry::triangulate::{triangulate, triangulate_dlt};
use geometry::{Camera, Distortion, Intrinsics};
use nalgebra::{Matrix3, Vector2, Vector3};
use opencv::core::{Mat, Point2d, Point3d, Vector, no_array};
use opencv::prelude::*;

fn mat3(m: &Matrix3<f64>) -> Mat {
    let rows: Vec<[f64; 3]> = (0..3).map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)]]).collect();
    Mat::from_slice_2d(&rows).unwrap()
}

fn dist(k: &Intrinsics) -> Mat {
    Mat::from_slice(&k.dist.to_opencv())
        .unwrap()
        .try_clone()
        .unwrap()
}

/// The simulated head's cameras (two-term radial) and both with a
/// `plumb_bob` and a rational lens, as real calibrations give them.
fn lens_variants() -> Vec<Camera> {
    let lenses = [
        Distortion::from_opencv(&[-0.28, 0.09, 0.0012, -0.0007, -0.011]).unwrap(),
        Distortion::from_opencv(&[0.42, -0.05, 0.0009, 0.0004, 0.002, 0.78, 0.06, 0.01]).unwrap(),
    ];
    let head = nico_scene().rig.cameras;
    let mut out = head.to_vec();
    for lens in lenses {
        for cam in head {
            let mut c = cam;
            c.intrinsics.dist = lens;
            out.push(c);
        }
    }
    out
}

/// Deterministic points in front of the cameras (no RNG dependency needed).
fn points(n: usize) -> Vec<Vector3<f64>> {
    (0..n)
        .map(|i| {
            let t = i as f64;
            Vector3::new(
                180.0 * (1.3 * t).sin(),
                120.0 * (0.7 * t).cos(),
                350.0 + 500.0 * (0.5 + 0.5 * (0.9 * t).sin()),
            )
        })
        .collect()
}

fn opencv_project(cam: &Camera, pts: &[Vector3<f64>]) -> Vec<Vector2<f64>> {
    let object: Vector<Point3d> = pts.iter().map(|p| Point3d::new(p.x, p.y, p.z)).collect();
    let mut rvec = Mat::default();
    opencv::calib3d::rodrigues(&mat3(&cam.camera_from_world), &mut rvec, &mut no_array()).unwrap();
    let t = -cam.camera_from_world * cam.center;
    let tvec = Mat::from_slice(&[t.x, t.y, t.z])
        .unwrap()
        .try_clone()
        .unwrap();
    let mut image: Vector<Point2d> = Vector::new();
    opencv::calib3d::project_points(
        &object,
        &rvec,
        &tvec,
        &mat3(&cam.intrinsics.k()),
        &dist(&cam.intrinsics),
        &mut image,
        &mut no_array(),
        0.0,
    )
    .unwrap();
    image.iter().map(|p| Vector2::new(p.x, p.y)).collect()
}

#[test]
fn projection_with_distortion_matches_project_points() {
    // OpenCV's model has no skew term, so compare with skew = 0.
    for cam in lens_variants() {
        assert_eq!(cam.intrinsics.skew, 0.0);
        let pts = points(60);
        for (p, theirs) in pts.iter().zip(opencv_project(&cam, &pts)) {
            let ours = cam.project(p).unwrap();
            assert!((ours - theirs).norm() < 1e-9, "{ours} vs {theirs}");
        }
    }
}

#[test]
fn undistortion_matches_undistort_points() {
    for cam in lens_variants() {
        undistortion_matches_for(&cam.intrinsics);
    }
}

fn undistortion_matches_for(k: &Intrinsics) {
    let pixels: Vector<Point2d> = (0..64)
        .map(|i| {
            Point2d::new(
                10.0 + 620.0 * f64::from(i % 8) / 7.0,
                10.0 + 460.0 * f64::from(i / 8) / 7.0,
            )
        })
        .collect();
    let mut normalised: Vector<Point2d> = Vector::new();
    // OpenCV iterates a fixed-point scheme; ask for many iterations and a tight epsilon.
    let criteria = opencv::core::TermCriteria::new(3, 200, 1e-15).unwrap();
    opencv::calib3d::undistort_points_iter(
        &pixels,
        &mut normalised,
        &mat3(&k.k()),
        &dist(k),
        &no_array(),
        &no_array(),
        criteria,
    )
    .unwrap();
    for (px, theirs) in pixels.iter().zip(normalised.iter()) {
        let ours = k.undistort_pixel(&Vector2::new(px.x, px.y)).unwrap();
        // Compare in pixels (times the focal length).
        let diff = (ours - Vector2::new(theirs.x, theirs.y)).norm() * k.fx;
        assert!(diff < 1e-6, "pixel ({}, {}): {diff} px apart", px.x, px.y);
    }
}

fn opencv_triangulate(cams: [&Camera; 2], pixels: &[[Vector2<f64>; 2]]) -> Vec<Vector3<f64>> {
    // OpenCV triangulates undistorted points with P = [R | -R C] on normalised coordinates.
    let mut sides: Vec<Mat> = Vec::new();
    for k in 0..2 {
        let pts: Vec<Vector2<f64>> = pixels
            .iter()
            .map(|px| cams[k].intrinsics.undistort_pixel(&px[k]).unwrap())
            .collect();
        let mut m =
            Mat::new_rows_cols_with_default(2, pts.len() as i32, opencv::core::CV_64F, 0.0.into())
                .unwrap();
        for (i, p) in pts.iter().enumerate() {
            *m.at_2d_mut::<f64>(0, i as i32).unwrap() = p.x;
            *m.at_2d_mut::<f64>(1, i as i32).unwrap() = p.y;
        }
        sides.push(m);
    }
    let proj = |c: &Camera| {
        let p = c.normalized_projection();
        let rows: Vec<[f64; 4]> = (0..3)
            .map(|r| [p[(r, 0)], p[(r, 1)], p[(r, 2)], p[(r, 3)]])
            .collect();
        Mat::from_slice_2d(&rows).unwrap()
    };
    let mut homogeneous = Mat::default();
    opencv::calib3d::triangulate_points(
        &proj(cams[0]),
        &proj(cams[1]),
        &sides[0],
        &sides[1],
        &mut homogeneous,
    )
    .unwrap();
    (0..pixels.len() as i32)
        .map(|i| {
            let h = |r| *homogeneous.at_2d::<f64>(r, i).unwrap();
            Vector3::new(h(0) / h(3), h(1) / h(3), h(2) / h(3))
        })
        .collect()
}

#[test]
fn triangulation_matches_triangulate_points() {
    let scene = nico_scene();
    let real = [scene.rig.cameras[0], scene.rig.cameras[1]];
    let mirror = scene.mirrors[1].plane;
    // Real cameras, and mirror cameras whose scene points lie at negative depth.
    let virt = real.map(|c| mirror.mirror_camera(&c));
    for (cams, pts) in [
        (real, points(40)),
        (
            virt,
            points(40)
                .into_iter()
                .map(|p| Vector3::new(p.x * 0.5, p.y * 0.5 + 150.0, 120.0 + 0.25 * p.z))
                .collect(),
        ),
    ] {
        let refs = [&cams[0], &cams[1]];
        let exact: Vec<[Vector2<f64>; 2]> = pts
            .iter()
            .map(|p| [cams[0].project(p).unwrap(), cams[1].project(p).unwrap()])
            .collect();
        let theirs = opencv_triangulate(refs, &exact);
        for ((p, px), t) in pts.iter().zip(&exact).zip(&theirs) {
            let ours = triangulate(refs, *px).unwrap();
            assert!(
                (ours - t).norm() < 1e-6 && (ours - p).norm() < 1e-6,
                "ours {ours}, OpenCV {t}, true {p}"
            );
        }
        // With noise our linear step agrees with OpenCV's DLT to well under the
        // noise, and our refined point never reprojects worse than OpenCV's.
        let noisy: Vec<[Vector2<f64>; 2]> = exact
            .iter()
            .enumerate()
            .map(|(i, px)| {
                let e = |s: f64| Vector2::new((s * 1.7).sin(), (s * 2.3).cos()) * 0.8;
                [px[0] + e(i as f64), px[1] + e(i as f64 + 0.5)]
            })
            .collect();
        let theirs = opencv_triangulate(refs, &noisy);
        for (px, t) in noisy.iter().zip(&theirs) {
            let dlt = triangulate_dlt(refs, *px).unwrap();
            // OpenCV does not scale the equations; observed gap up to 0.8% of the range.
            assert!(
                (dlt - t).norm() < 0.01 * t.norm(),
                "DLT {dlt} vs OpenCV {t}"
            );
            let ours = triangulate(refs, *px).unwrap();
            let err = |p: &Vector3<f64>| {
                (0..2)
                    .map(|k| (cams[k].project(p).unwrap() - px[k]).norm_squared())
                    .sum::<f64>()
            };
            assert!(
                err(&ours) <= err(t) + 1e-9,
                "ours reprojects at {} vs OpenCV {}",
                err(&ours),
                err(t)
            );
        }
    }
}

/// A calibration file written by OpenCV's own `FileStorage`, as the
/// calibration sample writes one, reads back to the same intrinsics.
#[test]
fn calibration_file_written_by_opencv_filestorage_reads_back() {
    use opencv::core::{FileStorage, FileStorage_Mode};
    let dir = tempfile::tempdir().unwrap();
    for cam in lens_variants() {
        let k = cam.intrinsics;
        let path = dir.path().join("camera.yaml");
        let mut fs =
            FileStorage::new(path.to_str().unwrap(), FileStorage_Mode::WRITE as i32, "").unwrap();
        opencv::core::write_i32(&mut fs, "image_width", k.width as i32).unwrap();
        opencv::core::write_i32(&mut fs, "image_height", k.height as i32).unwrap();
        opencv::core::write_mat(&mut fs, "camera_matrix", &mat3(&k.k())).unwrap();
        let d = Mat::from_slice(&k.dist.coefficients())
            .unwrap()
            .t()
            .unwrap()
            .to_mat()
            .unwrap();
        opencv::core::write_mat(&mut fs, "distortion_coefficients", &d).unwrap();
        opencv::core::write_f64(&mut fs, "avg_reprojection_error", 0.31).unwrap();
        fs.release().unwrap();
        let (read, kind) = formats::camera_file::read(&path).unwrap();
        assert_eq!(kind, formats::camera_file::CameraFileKind::OpenCv);
        assert_eq!(read, k);
    }
}
