//! The drift watch on the simulator, through the live stage: how soon each
//! change of the targets is found and how well it is calibrated
//! again, over seeds; false alarms over 10 unchanged runs of 60 poses; the
//! smallest change found within 10 samples; and what watching costs, as a
//! ratio to one calibration in the same run.
//!
//! `cargo bench -p mirror_proc --bench drift`

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::Instant;

use common::{AFTER_IDS, PIXEL_SIGMA, Run, data, interleave, roled, run};
use geometry::sim::{Counts, Scene, nico_scene};
use geometry::{Role, Sample};
use messages::{EpochState, Moved};
use mirror_proc::calibrate::{Method, calibrate};
use mirror_proc::drift::DriftMonitor;
use nalgebra::{Matrix3, Rotation3, Vector3};

const SEEDS: u64 = 8;

/// A change of the world, as the bench makes it.
#[derive(Clone, Copy)]
enum Change {
    Mirror { tilt_deg: f64, shift_mm: f64 },
    LeftCamera { pan_deg: f64 },
}

impl Change {
    fn apply(self, scene: &Scene, m: usize) -> Scene {
        let mut s = scene.clone();
        match self {
            Change::Mirror { tilt_deg, shift_mm } => {
                s.mirrors[m] = scene.mirrors[m].moved(tilt_deg, shift_mm)
            }
            Change::LeftCamera { pan_deg } => {
                s.rig.cameras[0] =
                    scene.rig.cameras[0].turned(&(Vector3::y() * pan_deg.to_radians()))
            }
        }
        s
    }
}

/// One live run: 30 calibration and 10 test poses of the unchanged world,
/// then 20 calibration poses and 10 direct views (`direct`) or test poses
/// of the changed one. Returns the run, its poses' ids and where the
/// change came.
fn changed_run(change: Change, seed: u64, direct: bool) -> (Run, Vec<u64>, usize, Scene) {
    let scene = nico_scene();
    let m = (seed % 3) as usize;
    let moved = change.apply(&scene, m);
    let before = data(
        &scene,
        m,
        Counts {
            train: 30,
            test: 10,
            direct: 0,
        },
        500 + seed,
        0,
    );
    let after = data(
        &moved,
        m,
        Counts {
            train: 20,
            test: if direct { 0 } else { 10 },
            direct: if direct { 10 } else { 0 },
        },
        900 + seed,
        AFTER_IDS,
    );
    let mut poses = interleave(
        roled(&before.train, Role::Train),
        roled(&before.test, Role::Test),
        3,
    );
    let at = poses.len();
    let second = if direct {
        roled(&after.direct, Role::Direct).collect::<Vec<_>>()
    } else {
        roled(&after.test, Role::Test).collect()
    };
    poses.extend(interleave(roled(&after.train, Role::Train), second, 2));
    let ids = poses.iter().map(|(s, _)| s.pose).collect();
    (run(&scene, &poses), ids, at, moved)
}

/// Samples after the change to the drifted calibration, and what it named.
fn found(r: &Run, ids: &[u64], at: usize) -> Option<(usize, Moved, u32)> {
    let c = r
        .calibrations
        .iter()
        .find(|c| c.epoch.state() == Some(EpochState::Drifted))?;
    let i = ids.iter().position(|p| *p == c.epoch.found_at_pose)?;
    Some((i + 1 - at.min(i + 1), c.epoch.moved()?, c.epoch.camera))
}

fn targets() {
    println!(
        "Targets, {SEEDS} seeds, {PIXEL_SIGMA} px (detections count from the first sample after the change)"
    );
    for (name, change, limit) in [
        (
            "mirror 1 deg + 5 mm",
            Change::Mirror {
                tilt_deg: 1.0,
                shift_mm: 5.0,
            },
            3,
        ),
        (
            "mirror 2 mm",
            Change::Mirror {
                tilt_deg: 0.0,
                shift_mm: 2.0,
            },
            5,
        ),
    ] {
        let (mut delays, mut angle, mut distance, mut fresh) = (Vec::new(), 0.0f64, 0.0f64, 0.0f64);
        for seed in 0..SEEDS {
            let (r, ids, at, moved) = changed_run(change, seed, false);
            let delay = found(&r, &ids, at).map(|(n, what, _)| match what {
                Moved::Mirror => n.to_string(),
                other => format!("{n} ({other:?})"),
            });
            delays.push(delay.unwrap_or_else(|| "-".into()));
            let truth = moved.mirrors[(seed % 3) as usize].plane;
            let Some(c) = r
                .calibrations
                .iter()
                .find(|c| c.epoch.epoch == 2 && c.samples + c.uncertainty.rejected_samples >= 15)
            else {
                continue;
            };
            let n = Vector3::new(c.plane[0], c.plane[1], c.plane[2]);
            angle = angle.max(n.angle(&truth.normal).to_degrees());
            distance = distance.max((c.plane[3] - truth.distance).abs());
            // A fresh run of a new robot from 15 samples of the moved
            // mirror, for comparison.
            let m = (seed % 3) as usize;
            let d = data(
                &moved,
                m,
                Counts {
                    train: 15,
                    test: 0,
                    direct: 0,
                },
                900 + seed,
                0,
            );
            let p = calibrate(&d.rig, &d.train, Method::JointKinematics)
                .unwrap()
                .plane
                .unwrap();
            fresh = fresh.max((p.distance - truth.distance).abs());
        }
        println!(
            "  {name:<22} found after {} samples (target <= {limit}); after 15 new samples the plane is at worst {angle:.3} deg / {distance:.2} mm off (a fresh 15-sample run: {fresh:.2} mm)",
            delays.join(", ")
        );
    }
    let (mut delays, mut worst, mut worst_sigmas) = (Vec::new(), [0.0f64; 3], [0.0f64; 3]);
    for seed in 0..SEEDS {
        let (r, ids, at, moved) = changed_run(Change::LeftCamera { pan_deg: 0.3 }, seed, true);
        let named = found(&r, &ids, at);
        delays.push(match named {
            Some((n, Moved::Camera, 0)) => n.to_string(),
            other => format!("{other:?}"),
        });
        let report = r.live.report();
        let Some(head) = report
            .calibration
            .as_ref()
            .and_then(|c| c.head_cameras.first())
        else {
            continue;
        };
        let found =
            Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(&head.camera_from_world));
        let truth = Rotation3::from_matrix_unchecked(moved.rig.cameras[0].camera_from_world);
        let e = (found * truth.inverse()).scaled_axis();
        for k in 0..3 {
            worst[k] = worst[k].max(e[k].to_degrees().abs());
            worst_sigmas[k] = worst_sigmas[k].max(e[k].to_degrees().abs() / head.sigma_deg[k]);
        }
    }
    println!(
        "  {:<22} found after {} samples (target <= 5), named the left camera; after 10 direct views its turn is at worst {:.3} deg (tilt), {:.3} (pan), {:.3} (about the optical axis) off, {:.1}, {:.1} and {:.1} of its stated 1-sigma",
        "left camera 0.3 deg",
        delays.join(", "),
        worst[0],
        worst[1],
        worst[2],
        worst_sigmas[0],
        worst_sigmas[1],
        worst_sigmas[2]
    );
}

fn false_alarms() {
    let scene = nico_scene();
    // More runs with DRIFT_FALSE_ALARM_RUNS=N.
    let runs: u64 = std::env::var("DRIFT_FALSE_ALARM_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10);
    let mut alarms = 0;
    for seed in 0..runs {
        let d = data(
            &scene,
            (seed % 3) as usize,
            Counts {
                train: 40,
                test: 10,
                direct: 10,
            },
            300 + seed,
            0,
        );
        let poses = interleave(
            roled(&d.train, Role::Train),
            roled(&d.test, Role::Test).chain(roled(&d.direct, Role::Direct)),
            2,
        );
        let r = run(&scene, &poses);
        alarms += r
            .calibrations
            .iter()
            .filter(|c| c.epoch.state() != Some(EpochState::Calibrated))
            .count();
    }
    println!("False alarms: {alarms} in {runs} unchanged runs of 60 poses");
}

/// Of `SEEDS` runs, how many found `change` within 10 samples.
fn found_within_10(change: Change) -> u64 {
    (0..SEEDS)
        .filter(|&seed| {
            let (r, ids, at, _) = changed_run(change, seed, false);
            found(&r, &ids, at).is_some_and(|(n, _, _)| n <= 10)
        })
        .count() as u64
}

fn smallest() {
    println!("Smallest change found within 10 samples (runs of {SEEDS} that found it)");
    let scan = |name: &str, sizes: &[f64], change: &dyn Fn(f64) -> Change| {
        let cells: Vec<String> = sizes
            .iter()
            .map(|&v| format!("{v}: {}/{SEEDS}", found_within_10(change(v))))
            .collect();
        println!("  {name:<26} {}", cells.join("  "));
    };
    scan("mirror tilt, deg", &[0.02, 0.05, 0.1, 0.2], &|v| {
        Change::Mirror {
            tilt_deg: v,
            shift_mm: 0.0,
        }
    });
    scan("mirror shift, mm", &[0.25, 0.5, 1.0, 2.0], &|v| {
        Change::Mirror {
            tilt_deg: 0.0,
            shift_mm: v,
        }
    });
    scan("left camera pan, deg", &[0.01, 0.02, 0.05, 0.1], &|v| {
        Change::LeftCamera { pan_deg: v }
    });
}

/// Scoring a sample against the calibration, as a ratio to calibrating
/// from the same 30 samples, medians of this run.
fn cost() {
    let scene = nico_scene();
    let d = data(
        &scene,
        0,
        Counts {
            train: 30,
            test: 200,
            direct: 0,
        },
        77,
        0,
    );
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let calibrations: Vec<f64> = (0..20)
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(calibrate(&d.rig, &d.train, Method::JointKinematics).unwrap());
            t.elapsed().as_secs_f64()
        })
        .collect();
    let cal = calibrate(&d.rig, &d.train, Method::JointKinematics).unwrap();
    let mut monitor = DriftMonitor::new(&d.rig, cal, PIXEL_SIGMA);
    let scores: Vec<f64> = d
        .test
        .iter()
        .map(|s: &Sample| {
            let t = Instant::now();
            std::hint::black_box(monitor.push(s));
            t.elapsed().as_secs_f64()
        })
        .collect();
    let (c, s) = (median(calibrations), median(scores));
    println!(
        "Cost: scoring a sample {:.1} us, {:.5}x one calibration from 30 samples ({:.2} ms)",
        s * 1e6,
        s / c,
        c * 1e3
    );
}

fn main() {
    // `cargo test --benches` runs benches with `--bench` absent: nothing to do.
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    // `cargo bench -p mirror_proc --bench drift -- targets cost` runs those
    // parts only.
    let asked: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let parts: [(&str, fn()); 4] = [
        ("targets", targets),
        ("false_alarms", false_alarms),
        ("smallest", smallest),
        ("cost", cost),
    ];
    if let Some(unknown) = asked.iter().find(|a| parts.iter().all(|(n, _)| n != *a)) {
        let names: Vec<&str> = parts.iter().map(|(n, _)| *n).collect();
        eprintln!("drift bench: no part named {unknown:?}; the parts are {names:?}");
        std::process::exit(2);
    }
    for (name, part) in parts {
        if asked.is_empty() || asked.iter().any(|a| a == name) {
            part();
        }
    }
}
