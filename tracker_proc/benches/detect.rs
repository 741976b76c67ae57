//! Detection time per stereo frame: our pass (normal and mirror-reversed
//! markers, one dictionary) against a plain OpenCV pass with the stock
//! dictionary, on the same rendered frames in the same run; and the
//! tracker stage's whole step (header checks, stamp order, `Mat` views over
//! the frame as laid out in shared memory, both images).
//!
//! The ratios print first: both passes timed frame by frame, interleaved
//! (the order alternating each frame) in rounds over the same frames, so
//! that the machine's load changes both alike; each round gives a ratio and
//! the spread over rounds says how far to trust it. The renderer is timed
//! against the tracker the same way.
//! Run: `cargo bench -p tracker_proc --bench detect`.

use camera_proc::render::Renderer;
use criterion::{Criterion, criterion_group, criterion_main};
use geometry::sim::{Counts, generate, nico_noise, nico_scene};
use geometry::sim::{Facing, SimWorld};
use messages::{Encoding, FrameHeader};
use opencv::core::Mat;
use opencv::prelude::*;
use std::hint::black_box;
use std::time::{Duration, Instant};
use tracker_proc::{Detector, StockPass, Tracked, Tracker};

/// The training poses the frames are rendered at.
fn poses() -> Vec<Vec<f64>> {
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
    data.train
        .iter()
        .map(|s| s.joints.clone().unwrap())
        .collect()
}

fn frames(poses: &[Vec<f64>]) -> Vec<[Mat; 2]> {
    let mut renderer = Renderer::new(SimWorld::nico(0).unwrap()).unwrap();
    poses
        .iter()
        .enumerate()
        .map(|(i, q)| {
            let ([l, r], _) = renderer.render_pair(q, Facing::Mirror, i as u64).unwrap();
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

/// Prints the median and range of the per-round ratios `a / b` of
/// [`interleaved`]'s `times` over `n` frames, and the middle round's times
/// per frame.
fn report(what: &str, names: [&str; 2], times: &[(Duration, Duration)], n: usize) {
    let mut ratios: Vec<f64> = times
        .iter()
        .map(|(a, b)| a.as_secs_f64() / b.as_secs_f64())
        .collect();
    ratios.sort_by(f64::total_cmp);
    let (median, lo, hi) = (
        ratios[ratios.len() / 2],
        ratios[0],
        ratios[ratios.len() - 1],
    );
    let per_frame = |d: Duration| d.as_secs_f64() * 1e3 / n as f64;
    let (a, b) = times[times.len() / 2];
    println!(
        "ratio {what} per stereo frame: {median:.3} (range {lo:.3} to {hi:.3} over {} rounds of {n} frames; {} {:.2} ms, {} {:.2} ms)",
        times.len(),
        names[0],
        per_frame(a),
        names[1],
        per_frame(b)
    );
}

/// Times `a` and `b` on each of `n` items in turn, alternating which goes
/// first, for `rounds` rounds; returns per-round total times (a, b).
fn interleaved(
    rounds: usize,
    n: usize,
    mut a: impl FnMut(usize),
    mut b: impl FnMut(usize),
) -> Vec<(Duration, Duration)> {
    (0..rounds)
        .map(|round| {
            let (mut ta, mut tb) = (Duration::ZERO, Duration::ZERO);
            for i in 0..n {
                let time = |f: &mut dyn FnMut(usize), total: &mut Duration| {
                    let t = Instant::now();
                    f(i);
                    *total += t.elapsed();
                };
                if (i + round) % 2 == 0 {
                    time(&mut a, &mut ta);
                    time(&mut b, &mut tb);
                } else {
                    time(&mut b, &mut tb);
                    time(&mut a, &mut ta);
                }
            }
            (ta, tb)
        })
        .collect()
}

/// Ratios measured in this run, interleaved, with their spread over rounds.
fn ratios(_: &mut Criterion) {
    // `cargo bench` passes --bench; under `cargo test` one short round shows it runs.
    let rounds = if std::env::args().any(|a| a == "--bench") {
        15
    } else {
        1
    };
    let poses = poses();
    let frames = frames(&poses);
    let n = frames.len();
    let stock = StockPass::new().unwrap();
    let mut ours = Detector::new(true).unwrap();
    let detect = |detector: &mut Detector, i: usize| {
        black_box((
            detector.detect(&frames[i][0]).unwrap(),
            detector.detect(&frames[i][1]).unwrap(),
        ));
    };
    let times = interleaved(
        rounds,
        n,
        |i| detect(&mut ours, i),
        |i| {
            black_box((
                stock.detect(&frames[i][0]).unwrap(),
                stock.detect(&frames[i][1]).unwrap(),
            ));
        },
    );
    report("ours / stock detectMarkers", ["ours", "stock"], &times, n);
    let mut renderer = Renderer::new(SimWorld::nico(0).unwrap()).unwrap();
    let times = interleaved(
        rounds,
        n,
        |i| {
            black_box(
                renderer
                    .render_pair(&poses[i], Facing::Mirror, i as u64)
                    .unwrap(),
            );
        },
        |i| detect(&mut ours, i),
    );
    report("render / track", ["render", "track"], &times, n);
}

fn bench(c: &mut Criterion) {
    let frames = frames(&poses());
    let mut group = c.benchmark_group("detect_stereo_frame");
    let stock = StockPass::new().unwrap();
    let mut i = 0;
    group.bench_function("baseline: stock detectMarkers", |b| {
        b.iter(|| {
            let f = &frames[i % frames.len()];
            i += 1;
            black_box((stock.detect(&f[0]).unwrap(), stock.detect(&f[1]).unwrap()))
        })
    });
    for (name, mirrored) in [
        ("ours: printed only", false),
        ("ours: printed + mirrored", true),
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

criterion_group!(benches, ratios, bench);
criterion_main!(benches);
