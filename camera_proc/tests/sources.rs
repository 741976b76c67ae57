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

/// A side-by-side video file (MJPG in AVI, written by OpenCV's own
/// `VideoWriter`) opens with what it declares, plays at its own rate by
/// default, and yields every frame split into its halves.
#[test]
fn a_side_by_side_video_file_declares_its_size_rate_and_codec_and_plays_every_frame() {
    use camera_proc::source::Captures;
    use opencv::videoio::VideoWriter;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stereo.avi");
    let fourcc = VideoWriter::fourcc('M', 'J', 'P', 'G').unwrap();
    let mut writer = VideoWriter::new(
        path.to_str().unwrap(),
        fourcc,
        15.0,
        opencv::core::Size::new(128, 48),
        false,
    )
    .unwrap();
    assert!(writer.is_opened().unwrap());
    let frames = 12;
    for k in 0..frames {
        // Left half dark, right half bright, both changing with k.
        let mut m =
            Mat::new_rows_cols_with_default(48, 128, opencv::core::CV_8UC1, Scalar::all(0.0))
                .unwrap();
        for r in 0..48 {
            for c in 0..128 {
                *m.at_2d_mut::<u8>(r, c).unwrap() =
                    if c < 64 { 40 + 5 * k } else { 200 - 5 * k } as u8;
            }
        }
        writer.write(&m).unwrap();
    }
    writer.release().unwrap();
    let mut source = Captures::side_by_side(path.to_str().unwrap()).unwrap();
    let info = source.info().clone();
    assert_eq!(
        (info.width, info.height, info.codec.as_str()),
        (128, 48, "MJPG"),
        "{info:?}"
    );
    assert_eq!(info.frames, Some(frames as u64));
    assert!((info.fps - 15.0).abs() < 1e-6, "{info:?}");
    assert_eq!(source.file_rate(), Some(info.fps));
    assert_eq!(source.size(), (64, 48));
    let (mut l, mut r) = (vec![0u8; 64 * 48], vec![0u8; 64 * 48]);
    for k in 0..frames {
        assert!(source.next_into(&mut l, &mut r).unwrap(), "frame {k}");
        let mean = |v: &[u8]| v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len() as f64;
        // JPEG is lossy: within a few grey levels.
        assert!(
            (mean(&l) - f64::from(40 + 5 * k)).abs() < 3.0,
            "frame {k}: left {}",
            mean(&l)
        );
        assert!(
            (mean(&r) - f64::from(200 - 5 * k)).abs() < 3.0,
            "frame {k}: right {}",
            mean(&r)
        );
    }
    assert!(
        !source.next_into(&mut l, &mut r).unwrap(),
        "the end of the file"
    );
}
