//! The drift watch on renders, over seeds: the launcher runs the whole
//! pipeline (rendered frames, the tracker, the live mirror stage, the
//! recorder) on mirror placement 0 with one change of the world after 30
//! calibration and 10 test poses, and the plan extended after it (20
//! calibration poses, 10 direct views). For each of the changes:
//!
//! - how many poses after the change it was found, and what was named;
//! - the moved mirror's plane against the truth from the first calibration
//!   of the new epoch with 15 samples (read from the recording);
//! - the knocked camera's found pose against the truth (the report), and
//!   per axis in its stated 1-sigma.
//!
//! A run with no change, 60 poses long (50 calibration, 10 test), counts
//! false alarms. Runs are not repeatable by seed: which frame of a pose's
//! dwell is sampled depends on timing. The sample-level bench
//! (`cargo bench -p mirror_proc --bench drift`) covers many more seeds at a
//! fixed 0.2 px, without frames; this one has the tracker's own noise and
//! the markers that hold still.
//!
//! `cargo bench -p tests --bench drift_renders` (25-35 s a run: three
//! changes and an unchanged run a seed); `MIRROR_BENCH_SEEDS=N` runs seeds 1..=N (default 4), and
//! `-- camera` (say) only the changes whose name holds that word. Under
//! `cargo test` nothing runs.

use std::path::Path;
use std::process::Command;

use geometry::Role;
use geometry::sim::{SimWorld, WorldChange};
use nalgebra::{Matrix3, Rotation3};
use recorder::channels::TopicId;
use recorder::reader::Recording;
use serde_json::Value;

/// The pose (from 0) at which the world changes: after the plan's own 40.
const AT_POSE: usize = 40;

/// Test poses of every run, after its calibration poses.
const TEST_POSES: usize = 10;

/// Calibration poses of an unchanged run: with its test poses, the 60
/// poses of the drift issue's false-alarm runs.
const UNCHANGED_TRAIN: usize = 50;

/// Samples (kept or set aside) the moved mirror's new epoch is judged at.
const NEW_SAMPLES: u32 = 15;

struct Scenario {
    name: &'static str,
    event: &'static str,
    change: Option<WorldChange>,
}

fn scenarios() -> [Scenario; 4] {
    [
        Scenario {
            name: "mirror 1 deg + 5 mm",
            event: "mirror = { tilt_deg = 1.0, shift_mm = 5.0 }",
            change: Some(WorldChange::Mirror {
                tilt_deg: 1.0,
                shift_mm: 5.0,
            }),
        },
        Scenario {
            name: "mirror 2 mm",
            event: "mirror = { tilt_deg = 0.0, shift_mm = 2.0 }",
            change: Some(WorldChange::Mirror {
                tilt_deg: 0.0,
                shift_mm: 2.0,
            }),
        },
        Scenario {
            name: "left camera 0.3 deg",
            event: "camera = { name = \"left\", rotate_deg = 0.3 }",
            change: Some(WorldChange::Camera {
                camera: 0,
                rotate_deg: 0.3,
                axis: 1,
            }),
        },
        Scenario {
            name: "nothing changes (60 poses)",
            event: "",
            change: None,
        },
    ]
}

/// What one run showed.
struct Outcome {
    /// Epochs after the first: what, and the poses and the mirror views
    /// (the views a moved mirror or a knocked camera shows in live) from
    /// the change to where it was found, both ends counted.
    found: Vec<(String, Option<(u64, usize)>)>,
    /// The new epoch's plane at 15 samples: (deg, mm) from the truth.
    plane: Option<(f64, f64)>,
    /// The found camera: deg from the truth, and per axis (tilt, pan,
    /// about the optical axis) in its stated 1-sigma.
    camera: Option<(f64, [f64; 3])>,
}

fn run(bins: &Path, scenario: &Scenario, seed: u64) -> Outcome {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("pipeline.toml");
    let event = if scenario.event.is_empty() {
        String::new()
    } else {
        format!("\n[[event]]\nat_pose = {AT_POSE}\n{}\n", scenario.event)
    };
    let train = if scenario.change.is_some() {
        AT_POSE - TEST_POSES
    } else {
        UNCHANGED_TRAIN
    };
    std::fs::write(
        &config,
        format!(
            "preset = \"nico\"\nmirrors = [0]\ntrain_poses = {train}\ntest_poses = {TEST_POSES}\ndirect_poses = 0\n\
             method = \"joint+kinematics\"\nsource = \"sim\"\nfps = 30.0\nmove_ms = 100\n\
             dwell_ms = 170\nseed = {seed}\nmin_train = 8\nrealtime_priority = 0\n{event}"
        ),
    )
    .unwrap();
    let out = dir.path().join("out");
    let output = Command::new(bins.join("pipeline"))
        .args(["--config", config.to_str().unwrap()])
        .args(["--out", out.to_str().unwrap()])
        .args(["--prefix", &tests::unique_prefix("driftbench")])
        .output()
        .expect("the launcher runs");
    assert!(
        output.status.success(),
        "{} (seed {seed}) failed: {}",
        scenario.name,
        String::from_utf8_lossy(&output.stderr)
    );
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let placement = &report["placements"][0];
    let no_epochs = Vec::new();
    let epochs = placement["epochs"].as_array().unwrap_or(&no_epochs);
    let plan = formats::plan::read(out.join("mirror0/plan.csv"), 0).unwrap();
    let index = |e: &Value, key: &str| {
        let pose = e[key].as_u64()?;
        plan.iter().position(|p| p.pose == pose)
    };
    let found = epochs
        .iter()
        .skip(1)
        .map(|e| {
            let views = index(e, "changed_at_pose")
                .zip(index(e, "found_at_pose"))
                .map(|(from, to)| {
                    plan[from..=to.max(from)]
                        .iter()
                        .filter(|p| p.role != Role::Direct)
                        .count()
                });
            let delay = e["found_after_poses"].as_u64().zip(views);
            (e["after"].as_str().unwrap_or("?").to_string(), delay)
        })
        .collect();
    // The epoch the scenario's change began (a false alarm before it
    // would begin another).
    let changed_epoch = epochs
        .iter()
        .find(|e| e["changed_at_pose"].is_u64())
        .and_then(|e| e["epoch"].as_u64());
    let truth = scenario
        .change
        .map(|change| SimWorld::nico(0).and_then(|w| w.changed(&change)).unwrap());
    let camera = match (scenario.change, &truth) {
        (Some(WorldChange::Camera { camera: k, .. }), Some(truth)) => {
            let deg = epochs
                .iter()
                .skip(1)
                .find_map(|e| e["head_cameras_deg"][0][1].as_f64());
            let entry = &placement["report"]["calibration"]["head_cameras"][0];
            let numbers = |v: &Value| -> Option<Vec<f64>> {
                v.as_array()?.iter().map(Value::as_f64).collect()
            };
            let axes = numbers(&entry["camera_from_world"])
                .zip(numbers(&entry["sigma_deg"]))
                .map(|(r, sigma)| {
                    let found = Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(&r));
                    let true_r =
                        Rotation3::from_matrix_unchecked(truth.rig.cameras[k].camera_from_world);
                    let e = (found * true_r.inverse()).scaled_axis();
                    [0, 1, 2].map(|i| e[i].to_degrees().abs() / sigma[i])
                });
            deg.zip(axes)
        }
        _ => None,
    };
    let plane = match (scenario.change, &truth, changed_epoch) {
        (Some(WorldChange::Mirror { .. }), Some(truth), Some(epoch)) => {
            let truth = truth.mirror.unwrap().plane;
            let by_topic = Recording::open(out.join("mirror0/recording.mcap"))
                .unwrap()
                .lossless_by_topic()
                .unwrap();
            by_topic[&TopicId::Calibration]
                .iter()
                .map(|b| bytemuck::from_bytes::<messages::CalibrationMsg>(b))
                .find(|c| {
                    u64::from(c.epoch.epoch) == epoch
                        && c.has_plane != 0
                        && c.samples + c.uncertainty.rejected_samples >= NEW_SAMPLES
                })
                .map(|c| {
                    let n = nalgebra::Vector3::new(c.plane[0], c.plane[1], c.plane[2]);
                    (
                        n.angle(&truth.normal).to_degrees(),
                        (c.plane[3] - truth.distance).abs(),
                    )
                })
        }
        _ => None,
    };
    Outcome {
        found,
        plane,
        camera,
    }
}

fn seeds_from_env() -> u64 {
    match std::env::var("MIRROR_BENCH_SEEDS") {
        Err(_) => 4,
        Ok(v) => match v.trim().parse::<u64>() {
            Ok(n) if n > 0 => n,
            _ => {
                eprintln!(
                    "drift_renders bench: MIRROR_BENCH_SEEDS={v:?} is not a count (1 or more)"
                );
                std::process::exit(2);
            }
        },
    }
}

fn main() {
    // `cargo test --benches` runs benches with `--bench` absent: nothing to do.
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let seeds = seeds_from_env();
    let bins = std::env::var_os("MIRROR_BENCH_BINS")
        .map_or_else(tests::release_stage_binaries, Into::into);
    println!(
        "The drift watch on renders, mirror 0, seeds 1..={seeds}: change at pose {AT_POSE}, \
         then 20 calibration poses and 10 direct views"
    );
    // `-- camera` runs the scenarios whose name holds a word given.
    let asked: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let chosen: Vec<Scenario> = scenarios()
        .into_iter()
        .filter(|s| asked.is_empty() || asked.iter().any(|a| s.name.contains(a.as_str())))
        .collect();
    if chosen.is_empty() {
        let names: Vec<&str> = scenarios().iter().map(|s| s.name).collect();
        eprintln!("drift_renders bench: no change named {asked:?}; the changes are {names:?}");
        std::process::exit(2);
    }
    for scenario in chosen {
        let (mut found, mut planes, mut cameras) = (Vec::new(), Vec::new(), Vec::new());
        for seed in 1..=seeds {
            let o = run(&bins, &scenario, seed);
            found.push(match o.found.as_slice() {
                [] => "-".to_string(),
                [(what, delay)] => format!(
                    "{} ({what})",
                    delay.map_or("?".to_string(), |(poses, views)| format!("{poses}/{views}"))
                ),
                more => format!("{} epochs: {more:?}", more.len() + 1),
            });
            if let Some((deg, mm)) = o.plane {
                planes.push(format!("{deg:.3} deg / {mm:.2} mm"));
            }
            if let Some((deg, [tilt, pan, axis])) = o.camera {
                cameras.push(format!("{deg:.3} ({tilt:.1}/{pan:.1}/{axis:.1})"));
            }
        }
        println!("  {}", scenario.name);
        println!(
            "    found after (poses/mirror views, what): {}",
            found.join(", ")
        );
        if !planes.is_empty() {
            println!(
                "    plane after {NEW_SAMPLES} new samples: {}",
                planes.join(", ")
            );
        }
        if !cameras.is_empty() {
            println!(
                "    camera found, deg from the truth (per axis, tilt/pan/optical axis, in its stated 1-sigma): {}",
                cameras.join(", ")
            );
        }
    }
}
