//! A changed world is noticed: samples scored against the calibration
//! made before the change raise the alarm within a few samples of it and
//! name what moved, and a world that does not change raises none.

use geometry::Sample;
use geometry::sim::{Counts, Dataset, NoiseModel, Scene, generate, nico_noise_scaled, nico_scene};
use mirror_proc::calibrate::{Calibration, Method, calibrate};
use mirror_proc::drift::{DriftMonitor, Moved};
use nalgebra::Vector3;

const PIXEL_SIGMA: f64 = 0.2;

fn noise() -> NoiseModel {
    nico_noise_scaled(PIXEL_SIGMA, 0.007)
}

fn data(scene: &Scene, mirror: usize, seed: u64) -> Dataset {
    let counts = Counts {
        train: 20,
        test: 30,
        direct: 40,
    };
    generate(scene, mirror, &noise(), counts, seed).unwrap()
}

/// Mirror and direct test views taking turns (the direct views after the
/// first 10, which the calibration holds).
fn stream(d: &Dataset) -> Vec<Sample> {
    d.test
        .iter()
        .zip(&d.direct[10..])
        .flat_map(|(m, s)| [m.clone(), s.clone()])
        .collect()
}

/// The calibration the monitor watches: the training poses and 10 direct
/// views, which fix the encoder offsets for the direct views to come.
fn calibration(d: &Dataset) -> Calibration {
    let samples: Vec<Sample> = d.train.iter().chain(&d.direct[..10]).cloned().collect();
    calibrate(&d.rig, &samples, Method::JointKinematics).unwrap()
}

/// `scene` with mirror `m` turned by `tilt_deg` about an axis in its
/// plane through its centre, then moved `shift_mm` along its normal.
fn moved_mirror(scene: &Scene, m: usize, tilt_deg: f64, shift_mm: f64) -> Scene {
    let mut scene = scene.clone();
    scene.mirrors[m] = scene.mirrors[m].moved(tilt_deg, shift_mm);
    scene
}

/// `scene` with its left camera turned by `deg` about its own vertical.
fn knocked_left(scene: &Scene, deg: f64) -> Scene {
    let mut scene = scene.clone();
    scene.rig.cameras[0] = scene.rig.cameras[0].turned(&(Vector3::y() * deg.to_radians()));
    scene
}

/// Streams `before` then `after` into a monitor of `cal`; returns how
/// many samples after the change it took and what it named.
fn detect(
    cal: &Calibration,
    d: &Dataset,
    before: &[Sample],
    after: &[Sample],
) -> Option<(usize, Moved)> {
    let mut monitor = DriftMonitor::new(&d.rig, cal.clone(), PIXEL_SIGMA);
    for s in before {
        if let Some(drift) = monitor.push(s) {
            panic!(
                "false alarm before the change at pose {}: {drift:?}",
                s.pose
            );
        }
    }
    for (i, s) in after.iter().enumerate() {
        if let Some(drift) = monitor.push(s) {
            return Some((i + 1, drift.moved.clone()));
        }
    }
    None
}

/// 10 runs of 60 poses, one wrong pairing in each.
#[test]
fn an_unchanged_world_raises_no_alarm() {
    let scene = nico_scene();
    let mut scored = 0;
    for seed in 0..10 {
        let d = data(&scene, (seed % 3) as usize, 900 + seed);
        let cal = calibration(&d);
        let mut samples = stream(&d);
        // One wrong pairing among them: a single bad sample is no change.
        samples[20].pixels = samples[30].pixels;
        scored += samples.len();
        assert_eq!(detect(&cal, &d, &samples, &[]), None);
    }
    println!("{scored} samples scored over 10 runs, no alarm");
}

#[test]
fn a_moved_mirror_is_found_within_a_few_samples_and_named() {
    let scene = nico_scene();
    let mut worst = [0usize; 2];
    for seed in 0..6 {
        let m = (seed % 3) as usize;
        let d = data(&scene, m, 700 + seed);
        let cal = calibration(&d);
        let before = &d.test[..10];
        for (case, (tilt, shift)) in [(1.0, 5.0), (0.0, 2.0)].into_iter().enumerate() {
            let moved = data(&moved_mirror(&scene, m, tilt, shift), m, 800 + seed);
            let found = detect(&cal, &d, before, &moved.test);
            let Some((n, Moved::Mirror)) = found else {
                panic!("seed {seed}, tilt {tilt} deg, shift {shift} mm: {found:?}");
            };
            worst[case] = worst[case].max(n);
        }
    }
    println!(
        "mirror 1 deg + 5 mm: found within {} samples; 2 mm: within {}",
        worst[0], worst[1]
    );
    assert!(worst[0] <= 3 && worst[1] <= 5, "{worst:?}");
}

#[test]
fn a_knocked_camera_is_found_and_named() {
    let scene = nico_scene();
    let mut worst = 0;
    for seed in 0..6 {
        let m = (seed % 3) as usize;
        let d = data(&scene, m, 500 + seed);
        let cal = calibration(&d);
        let before = stream(&d);
        let knocked = data(&knocked_left(&scene, 0.3), m, 600 + seed);
        let found = detect(&cal, &d, &before[..10], &stream(&knocked));
        let Some((n, Moved::Camera(name))) = found else {
            panic!("seed {seed}: {found:?}");
        };
        assert_eq!(name, d.rig.names[0]);
        worst = worst.max(n);
    }
    println!("left camera 0.3 deg: found within {worst} samples");
    assert!(worst <= 5, "{worst}");
}

/// Changes too small for any one sample to show (their errors stay near
/// the noise) add up over the samples after them, and are named by the
/// change that explains them.
#[test]
fn small_changes_add_up_and_are_named() {
    let scene = nico_scene();
    let mut worst = [0usize; 2];
    for seed in 0..6 {
        let m = (seed % 3) as usize;
        let d = data(&scene, m, 300 + seed);
        let cal = calibration(&d);
        let before = stream(&d);
        let tilted = data(&moved_mirror(&scene, m, 0.05, 0.0), m, 400 + seed);
        let found = detect(&cal, &d, &before[..10], &tilted.test);
        let Some((n, Moved::Mirror)) = found else {
            panic!("seed {seed}, mirror tilted 0.05 deg: {found:?}");
        };
        worst[0] = worst[0].max(n);
        let knocked = data(&knocked_left(&scene, 0.1), m, 400 + seed);
        let found = detect(&cal, &d, &before[..10], &stream(&knocked));
        let Some((n, Moved::Camera(name))) = found else {
            panic!("seed {seed}, left camera turned 0.1 deg: {found:?}");
        };
        assert_eq!(name, d.rig.names[0], "seed {seed}");
        worst[1] = worst[1].max(n);
    }
    println!(
        "mirror tilted 0.05 deg: found within {} samples; left camera 0.1 deg: within {}",
        worst[0], worst[1]
    );
    assert!(worst[0] <= 10 && worst[1] <= 10, "{worst:?}");
}
