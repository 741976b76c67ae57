//! Our candidate search against OpenCV's own: the border scanner finds every
//! border `findContours` (`RETR_LIST`, `CHAIN_APPROX_NONE`) finds, point for
//! point and in the same order, and the detector's candidates are the
//! quadrilaterals OpenCV 4.6's `detectMarkers` pass gives (its markers and
//! its rejected candidates, `minMarkerDistanceRate` 0), on realistic
//! renders and on the real photographs.

use std::path::Path;

use geometry::sim::{Facing, SimWorld, nico_train_poses};
use opencv::core::{Mat, Point, Point2f, Vector};
use opencv::imgcodecs;
use opencv::imgproc;
use opencv::prelude::*;
use renderer::Renderer;
use tracker_proc::contours::BorderScanner;
use tracker_proc::threshold::MeanThreshold;
use tracker_proc::{Detector, Options};

/// Realistic renders of the arm in the mirror and the photographs.
fn images() -> Vec<(String, Mat)> {
    let mut out = Vec::new();
    let mut renderer = Renderer::new(SimWorld::nico(0).unwrap()).unwrap();
    for (i, q) in nico_train_poses(0, 3, 4).unwrap().iter().enumerate() {
        let ([l, r], _) = renderer.render_pair(q, Facing::Mirror, i as u64).unwrap();
        for (k, v) in [l, r].iter().enumerate() {
            let m = Mat::from_slice(v).unwrap();
            let m = m.reshape(1, 480).unwrap().try_clone().unwrap();
            out.push((format!("render {i} camera {k}"), m));
        }
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/real_markers");
    let mut photos: Vec<_> = std::fs::read_dir(&root)
        .unwrap()
        .map(|d| d.unwrap().path())
        .filter(|d| d.is_dir())
        .flat_map(|d| std::fs::read_dir(d).unwrap())
        .map(|f| f.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "jpg" || e == "png"))
        .collect();
    photos.sort();
    for p in photos {
        let m = imgcodecs::imread(p.to_str().unwrap(), imgcodecs::IMREAD_GRAYSCALE).unwrap();
        out.push((p.display().to_string(), m));
    }
    out
}

/// OpenCV's threshold as `detectMarkers` makes it (constant 7).
fn adaptive_threshold(image: &Mat, window: i32) -> Mat {
    let mut binary = Mat::default();
    imgproc::adaptive_threshold(
        image,
        &mut binary,
        255.0,
        imgproc::ADAPTIVE_THRESH_MEAN_C,
        imgproc::THRESH_BINARY_INV,
        window,
        7.0,
    )
    .unwrap();
    binary
}

/// The borders `findContours` (`RETR_LIST`, `CHAIN_APPROX_NONE`) finds in `binary`.
fn their_borders(binary: &Mat) -> Vec<Vec<Point>> {
    let mut theirs = Vector::<Vector<Point>>::new();
    imgproc::find_contours_def(
        binary,
        &mut theirs,
        imgproc::RETR_LIST,
        imgproc::CHAIN_APPROX_NONE,
    )
    .unwrap();
    theirs.iter().map(|c| c.to_vec()).collect()
}

/// Every border `scanner` finds in `binary`.
fn our_borders(scanner: &mut BorderScanner, binary: &Mat) -> Vec<Vec<Point>> {
    let mut ours = Vec::new();
    scanner.scan(
        binary.data_bytes().unwrap(),
        binary.cols() as usize,
        binary.rows() as usize,
        binary.step1(0).unwrap(),
        0..=usize::MAX,
        |p| ours.push(p.to_vec()),
    );
    ours
}

#[test]
fn the_border_scanner_finds_what_find_contours_finds() {
    let mut scanner = BorderScanner::new();
    let (mut borders, mut points) = (0, 0);
    for (name, image) in images() {
        for window in [3, 13, 23] {
            let binary = adaptive_threshold(&image, window);
            let theirs = their_borders(&binary);
            let ours = our_borders(&mut scanner, &binary);
            assert_eq!(ours.len(), theirs.len(), "{name}, window {window}: borders");
            for (k, (a, b)) in ours.iter().zip(&theirs).enumerate() {
                assert_eq!(a, b, "{name}, window {window}: border {k}");
                points += a.len();
            }
            borders += ours.len();
        }
    }
    println!("{borders} borders, {points} points, all as findContours'");
}

/// Region tracking scans windows of many shapes with one scanner: an image
/// after one of another shape but the same framed size (6 x 7 after
/// 4 x 10: 8 x 9 = 6 x 12 bytes) is scanned as on its own. Reusing the
/// buffer by its size alone left the first image's pixels in the second's
/// frame, and the trace walked off the buffer (a tracker panic in a demo).
#[test]
fn images_of_another_shape_are_scanned_afresh() {
    let binary = |w: usize, h: usize, on: &dyn Fn(usize, usize) -> bool| {
        let bytes: Vec<u8> = (0..w * h)
            .map(|i| if on(i % w, i / w) { 255 } else { 0 })
            .collect();
        Mat::from_slice(&bytes)
            .unwrap()
            .reshape(1, h as i32)
            .unwrap()
            .try_clone()
            .unwrap()
    };
    let first = binary(4, 10, &|_, _| true);
    let second = binary(6, 7, &|x, y| (x + y) % 3 != 0);
    let mut scanner = BorderScanner::new();
    our_borders(&mut scanner, &first);
    assert_eq!(our_borders(&mut scanner, &second), their_borders(&second));
}

#[test]
fn the_threshold_is_adaptive_thresholds() {
    let mut ours = MeanThreshold::new();
    let mut pixels = 0;
    for (name, image) in images() {
        let (w, h) = (image.cols() as usize, image.rows() as usize);
        let grey = image.data_bytes().unwrap();
        let stride = image.step1(0).unwrap();
        ours.prepare(grey, w, h, stride, 23);
        let mut out = vec![0u8; w * h];
        for window in (3..=23).step_by(2) {
            let theirs = adaptive_threshold(&image, window);
            ours.binary_inv(grey, window as usize, 7.0, &mut out, 0, w);
            let theirs = theirs.data_bytes().unwrap();
            let differ = (0..w * h)
                .filter(|&i| (theirs[i] != 0) != (out[i] != 0))
                .count();
            assert_eq!(differ, 0, "{name}, window {window}: pixels that differ");
            pixels += w * h;
        }
    }
    println!("{pixels} pixels thresholded as adaptiveThreshold does");
}

/// A quadrilateral's corners in a fixed order (OpenCV turns the corners of
/// the markers it reads to the code's first corner).
fn key(q: &[Point2f; 4]) -> Vec<(i64, i64)> {
    let mut k: Vec<_> = q
        .iter()
        .map(|p| ((p.x * 16.0) as i64, (p.y * 16.0) as i64))
        .collect();
    k.sort();
    k
}

#[test]
fn the_candidates_are_opencvs() {
    let mut ours = Detector::new(true).unwrap();
    let mut theirs = Detector::with_options(Options {
        own_search: false,
        ..Options::new(true)
    })
    .unwrap();
    let mut total = 0;
    for (name, image) in images() {
        let mut a: Vec<_> = ours
            .candidates(&image)
            .unwrap()
            .iter()
            .map(|(q, _)| key(q))
            .collect();
        let mut b: Vec<_> = theirs
            .candidates(&image)
            .unwrap()
            .iter()
            .map(|(q, _)| key(q))
            .collect();
        a.sort();
        b.sort();
        assert_eq!(a, b, "{name}");
        total += a.len();
    }
    assert!(total > 100, "{total} candidates");
    println!("{total} candidates, all as OpenCV's");
}

#[test]
fn an_empty_or_tiny_image_has_no_candidates() {
    let mut detector = Detector::new(true).unwrap();
    for (rows, cols) in [(0, 0), (1, 1), (2, 3), (5, 5)] {
        let image = Mat::new_rows_cols_with_default(
            rows,
            cols,
            opencv::core::CV_8UC1,
            opencv::core::Scalar::all(0.0),
        )
        .unwrap();
        assert!(detector.detect(&image).unwrap().is_empty(), "{rows}x{cols}");
    }
}
