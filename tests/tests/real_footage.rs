//! Real footage through the pipeline: a side-by-side stereo video made from
//! real photographs (the real-image set's, in `tests/data/real_markers`),
//! played by `camera_proc device FILE --lockstep 1` into `tracker_proc run`,
//! loses no frame, and the tracker's detections of each frame are what our
//! detector finds on that frame as the camera stage decodes it.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use camera_proc::source::{Captures, StereoSource};
use messages::{MAX_MARKERS, topics};
use opencv::core::{self, Mat, Size};
use opencv::imgcodecs;
use opencv::prelude::*;
use opencv::videoio::VideoWriter;
use runtime::Bus;
use tests::{KillOnDrop, stage_binaries, unique_prefix};
use tracker_proc::Detector;

const SIDE: i32 = 640;

/// Writes a side-by-side MJPG video of `frames` stereo pairs: left the
/// photograph k, right the mirror image of photograph k + 1.
fn write_video(path: &Path, frames: usize) {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/real_markers/eurobot");
    let mut photos: Vec<_> = std::fs::read_dir(&data)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "jpg"))
        .collect();
    photos.sort();
    let read = |k: usize| {
        let m = imgcodecs::imread(&photos[k % photos.len()], imgcodecs::IMREAD_GRAYSCALE).unwrap();
        assert_eq!((m.cols(), m.rows()), (SIDE, SIDE));
        m
    };
    let mut writer = VideoWriter::new(
        path.to_str().unwrap(),
        VideoWriter::fourcc('M', 'J', 'P', 'G').unwrap(),
        30.0,
        Size::new(2 * SIDE, SIDE),
        false,
    )
    .unwrap();
    assert!(writer.is_opened().unwrap());
    for k in 0..frames {
        let mut right = Mat::default();
        core::flip(&read(k + 1), &mut right, 1).unwrap();
        let mut pair = Mat::default();
        core::hconcat2(&read(k), &right, &mut pair).unwrap();
        writer.write(&pair).unwrap();
    }
    writer.release().unwrap();
}

/// Each frame's detections as (id, mirrored, centre), sorted.
type Seen = Vec<(u32, u32, [i64; 2])>;

fn seen<'a>(markers: impl Iterator<Item = &'a messages::Marker>) -> Seen {
    // Centres to 1e-6 px: the same pixels through the same code agree exactly.
    let mut v: Seen = markers
        .map(|m| {
            (
                m.id,
                m.mirrored,
                [(m.center[0] * 1e6) as i64, (m.center[1] * 1e6) as i64],
            )
        })
        .collect();
    v.sort();
    v
}

#[test]
fn a_stereo_video_of_real_photographs_plays_through_the_tracker_without_loss() {
    let dir = tempfile::tempdir().unwrap();
    let video = dir.path().join("real_stereo.avi");
    let frames = 40;
    write_video(&video, frames);

    // What the tracker should report: our detector on the frames exactly as
    // the camera stage decodes them.
    let mut source = Captures::side_by_side(video.to_str().unwrap()).unwrap();
    assert_eq!(source.size(), (SIDE as u32, SIDE as u32));
    let mut detector = Detector::new(true).unwrap();
    // Per camera: the markers a frame message holds (the first MAX_MARKERS
    // found) and how many it counts as overflow.
    let mut expected: Vec<[(Seen, u32); 2]> = Vec::new();
    let (mut l, mut r) = (
        vec![0u8; (SIDE * SIDE) as usize],
        vec![0u8; (SIDE * SIDE) as usize],
    );
    while source.next_into(&mut l, &mut r).unwrap() {
        let mut pair: [(Seen, u32); 2] = Default::default();
        for (k, image) in [&l, &r].into_iter().enumerate() {
            let mat = Mat::new_rows_cols_with_data(SIDE, SIDE, image.as_slice()).unwrap();
            let found = detector.detect(&mat).unwrap();
            let kept = found.len().min(MAX_MARKERS);
            pair[k] = (seen(found[..kept].iter()), (found.len() - kept) as u32);
        }
        expected.push(pair);
    }
    assert_eq!(expected.len(), frames);
    let markers: usize = expected.iter().map(|p| p[0].0.len() + p[1].0.len()).sum();
    let mirrored: usize = expected
        .iter()
        .map(|p| p[1].0.iter().filter(|m| m.1 == 1).count())
        .sum();
    assert!(markers >= frames, "only {markers} markers in the footage");
    assert!(mirrored > frames / 2, "only {mirrored} mirrored markers");

    let prefix = unique_prefix("footage");
    let bins = stage_binaries();
    // The camera first: it creates the lossless services and waits for the tracker.
    let mut camera = KillOnDrop(
        Command::new(bins.join("camera_proc"))
            .args(["device", "--prefix", &prefix, "--lockstep", "1"])
            .arg(&video)
            .spawn()
            .unwrap(),
    );
    let started = Instant::now();
    let bus = Bus::new(&prefix, "footage_test").unwrap();
    while !bus.service_exists(topics::TopicId::Frames).unwrap() {
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "no frames service"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let detections = bus.subscriber::<topics::Detections>().unwrap();
    let _tracker = KillOnDrop(
        Command::new(bins.join("tracker_proc"))
            // Each frame is another photograph: every image searched whole.
            .args(["run", "--prefix", &prefix, "--full-scan-every", "1"])
            .spawn()
            .unwrap(),
    );
    let mut got = Vec::new();
    while got.len() < frames {
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "{} of {frames} frames' detections after 120 s",
            got.len()
        );
        match detections.receive().unwrap() {
            Some(d) => got.push(d),
            None => std::thread::sleep(Duration::from_millis(1)),
        }
    }
    let status = camera.0.wait().unwrap();
    assert!(status.success(), "camera_proc: {status}");
    for (k, d) in got.iter().enumerate() {
        assert_eq!(d.seq, k as u64, "frame {k} came as seq {}", d.seq);
        for cam in 0..2 {
            let c = &d.cameras[cam];
            assert_eq!(
                (seen(c.iter()), c.overflow),
                expected[k][cam],
                "frame {k} camera {cam}"
            );
        }
    }
    eprintln!("{frames} frames, {markers} markers ({mirrored} mirrored), none lost");
}
