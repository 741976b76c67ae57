//! The directory-of-pairs source reads back exactly what was written.

use camera_proc::source::{ImagePairs, StereoSource};
use opencv::core::{Mat, Scalar, Vector};
use opencv::prelude::*;

fn write_png(path: &std::path::Path, value: f64) -> Vec<u8> {
    let mut m =
        Mat::new_rows_cols_with_default(48, 64, opencv::core::CV_8UC1, Scalar::all(value)).unwrap();
    // A gradient so row order matters.
    for r in 0..48 {
        *m.at_2d_mut::<u8>(r, 3).unwrap() = (r * 5) as u8;
    }
    opencv::imgcodecs::imwrite(path, &m, &Vector::new()).unwrap();
    m.data_bytes().unwrap().to_vec()
}

#[test]
fn image_pairs_play_in_name_order() {
    let dir = tempfile::tempdir().unwrap();
    let a = (
        write_png(&dir.path().join("0001_left.png"), 10.0),
        write_png(&dir.path().join("0001_right.png"), 20.0),
    );
    let b = (
        write_png(&dir.path().join("0002_left.png"), 30.0),
        write_png(&dir.path().join("0002_right.png"), 40.0),
    );
    let mut source = ImagePairs::open(dir.path()).unwrap();
    assert_eq!(source.size(), (64, 48));
    let (mut l, mut r) = (vec![0u8; 64 * 48], vec![0u8; 64 * 48]);
    for expected in [&a, &b] {
        assert!(source.next_into(&mut l, &mut r).unwrap());
        assert_eq!((&l, &r), (&expected.0, &expected.1));
    }
    assert!(
        !source.next_into(&mut l, &mut r).unwrap(),
        "the end of the pairs"
    );
}

#[test]
fn a_missing_right_image_is_named() {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("7_left.png"), 1.0);
    let e = ImagePairs::open(dir.path()).err().unwrap().to_string();
    assert!(e.contains("7_left.png") && e.contains("7_right.png"), "{e}");
}
