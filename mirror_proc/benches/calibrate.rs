//! Calibration time per method at 10 and 50 samples (nico preset, seeded),
//! beside a baseline measured in the same run: triangulating the same
//! samples through the real cameras, the least work any method does. Each
//! method also as one plain least-squares fit (no uncertainty, no outlier
//! test: what calibrating was before they came in), so that their cost
//! reads as a ratio.
//! Run: `cargo bench -p mirror_proc --bench calibrate`.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use geometry::sim::{Counts, generate, nico_noise, nico_scene};
use geometry::triangulate::triangulate;
use mirror_proc::calibrate::{CalibrateOptions, Method, calibrate, calibrate_with};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let scene = nico_scene();
    let data = generate(
        &scene,
        0,
        &nico_noise(),
        Counts {
            train: 50,
            test: 0,
            direct: 0,
        },
        1,
    )
    .unwrap();
    let mut group = c.benchmark_group("calibrate");
    for n in [10, 50] {
        let samples = &data.train[..n];
        group.bench_with_input(
            BenchmarkId::new("baseline: triangulate samples", n),
            samples,
            |b, s| {
                b.iter(|| {
                    for x in s {
                        black_box(triangulate(data.rig.camera_refs(), x.pixels).unwrap());
                    }
                })
            },
        );
        let plain = CalibrateOptions::plain();
        for method in Method::ALL {
            group.bench_with_input(
                BenchmarkId::new(format!("{method}, plain least squares"), n),
                samples,
                |b, s| b.iter(|| black_box(calibrate_with(&data.rig, s, method, plain).unwrap())),
            );
            group.bench_with_input(BenchmarkId::new(method.as_str(), n), samples, |b, s| {
                b.iter(|| black_box(calibrate(&data.rig, s, method).unwrap()))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
