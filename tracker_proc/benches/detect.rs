//! Detection time per stereo frame: our pass (normal and mirror-reversed
//! markers, one dictionary) against a plain OpenCV pass with the stock
//! dictionary, on the same rendered frames in the same run; and the
//! tracker stage's whole step (header checks, stamp order, `Mat` views over
//! the frame as laid out in shared memory, both images).
//! Run: `cargo bench -p tracker_proc --bench detect`.

use camera_proc::render::Renderer;
use criterion::{Criterion, criterion_group, criterion_main};
use geometry::sim::{Counts, generate, nico_noise, nico_scene};
use geometry::sim::{Facing, SimWorld};
use messages::{Encoding, FrameHeader};
use opencv::core::Mat;
use opencv::prelude::*;
use std::hint::black_box;
use tracker_proc::{Detector, Tracked, Tracker};

fn frames() -> Vec<[Mat; 2]> {
    let data = generate(
        &nico_scene(),
        0,
        &nico_noise(),
        Counts {
            train: 20,
            test: 0,
            direct: 0,
        },
        4,
    )
    .unwrap();
    let mut renderer = Renderer::new(SimWorld::nico(0).unwrap()).unwrap();
    data.train
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let ([l, r], _) = renderer
                .render_pair(s.joints.as_ref().unwrap(), Facing::Mirror, i as u64)
                .unwrap();
            let mat = |v: Vec<u8>| {
                Mat::from_slice(&v)
                    .unwrap()
                    .reshape(1, 480)
                    .unwrap()
                    .try_clone()
                    .unwrap()
            };
            [mat(l), mat(r)]
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let frames = frames();
    let mut group = c.benchmark_group("detect_stereo_frame");
    for (name, mirrored) in [
        ("baseline: stock dictionary", false),
        ("ours: normal + mirrored", true),
    ] {
        let mut detector = Detector::new(mirrored).unwrap();
        let mut i = 0;
        group.bench_function(name, |b| {
            b.iter(|| {
                let f = &frames[i % frames.len()];
                i += 1;
                black_box((
                    detector.detect(&f[0]).unwrap(),
                    detector.detect(&f[1]).unwrap(),
                ))
            })
        });
    }
    // The whole step on the same frames, each as one stereo payload.
    let payloads: Vec<Vec<u8>> = frames
        .iter()
        .map(|[l, r]| [l.data_bytes().unwrap(), r.data_bytes().unwrap()].concat())
        .collect();
    let mut tracker = Tracker::new(true).unwrap();
    let mut seq = 0u64;
    group.bench_function("ours: the whole tracker step", |b| {
        b.iter(|| {
            let header = FrameHeader {
                seq,
                stamp_ns: seq as i64 + 1,
                published_ns: 0,
                width: 640,
                height: 480,
                stride: 640,
                encoding: Encoding::Mono8 as u32,
            };
            let payload = &payloads[seq as usize % payloads.len()];
            seq += 1;
            let tracked = tracker.step(&header, payload).unwrap();
            assert!(matches!(tracked, Tracked::Detections(_)));
            black_box(tracked)
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
