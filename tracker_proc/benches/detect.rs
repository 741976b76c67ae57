//! Detection time per stereo frame: our pass (normal and mirror-reversed
//! markers, one dictionary) against a plain OpenCV pass with the stock
//! dictionary, on the same rendered frames in the same run.
//! Run: `cargo bench -p tracker_proc --bench detect`.

use camera_proc::render::Renderer;
use criterion::{Criterion, criterion_group, criterion_main};
use geometry::sim::{Counts, generate, nico_noise, nico_scene};
use geometry::sim::{Facing, SimWorld};
use opencv::core::Mat;
use opencv::prelude::*;
use std::hint::black_box;
use tracker_proc::Detector;

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
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
