//! A run whose world changes under it (`[[event]]`): the mirror is bumped,
//! then the left camera knocked. The stage finds each change, names it,
//! and calibrates again; the figures are the truth's after each change. A
//! replay of the recording gives the same epochs, bit for bit.

use std::path::Path;
use std::process::Command;

use recorder::channels::TopicId;
use recorder::reader::Recording;
use tests::{stage_binaries, unique_prefix};

const CONFIG: &str = "preset = \"nico\"\nmirrors = [0]\ntrain_poses = 30\ntest_poses = 10\n\
    direct_poses = 10\nmethod = \"joint+kinematics\"\nsource = \"sim\"\nfps = 30.0\n\
    move_ms = 100\ndwell_ms = 170\nseed = 3\nmin_train = 8\nrealtime_priority = 0\n\n\
    [[event]]\nat_pose = 35\nmirror = { tilt_deg = 1.0, shift_mm = 5.0 }\n\n\
    [[event]]\nat_pose = 85\ncamera = { name = \"left\", rotate_deg = 0.3 }\n";

fn pipeline(args: &[&str]) -> String {
    let output = Command::new(stage_binaries().join("pipeline"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "pipeline {args:?} failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8_lossy(&output.stdout).into_owned()
}

fn calibrations(path: &Path) -> Vec<messages::CalibrationMsg> {
    let by_topic = Recording::open(path).unwrap().lossless_by_topic().unwrap();
    by_topic[&TopicId::Calibration]
        .iter()
        .map(|bytes| *bytemuck::from_bytes::<messages::CalibrationMsg>(bytes))
        .collect()
}

#[test]
fn a_moved_mirror_and_a_knocked_camera_are_found_and_calibrated_again() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("pipeline.toml");
    std::fs::write(&config, CONFIG).unwrap();
    let out = dir.path().join("out");
    let stdout = pipeline(&[
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--prefix",
        &unique_prefix("drift"),
    ]);
    eprintln!("{stdout}");
    assert!(stdout.contains("When the world changed"), "{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let placement = &report["placements"][0];
    let epochs = placement["epochs"].as_array().unwrap();
    assert_eq!(epochs.len(), 3, "{placement}");
    let (mirror, camera) = (&epochs[1], &epochs[2]);
    assert_eq!(mirror["after"], "mirror", "{mirror}");
    assert_eq!(camera["after"], "camera left", "{camera}");
    // Found within a few poses of each change.
    assert!(
        mirror["found_after_poses"].as_u64().unwrap() <= 3,
        "{mirror}"
    );
    assert!(
        camera["found_after_poses"].as_u64().unwrap() <= 5,
        "{camera}"
    );
    // Each epoch's plane against the world of its time: the moved mirror's
    // after the first change. The epochs' samples are few, so the plane's
    // distance is held to its own stated 1-sigma (4 of them) and to 1 mm,
    // the worst of 16 seeds in the drift bench; its angle to 0.05 deg.
    for e in epochs {
        let (angle, distance, sigma) = (
            e["plane_angle_deg"].as_f64().unwrap(),
            e["plane_distance_mm"].as_f64().unwrap(),
            e["plane_distance_sigma_mm"]
                .as_f64()
                .expect("distance sigma stated"),
        );
        assert!(angle < 0.05, "{e}");
        assert!(distance < 4.0 * sigma && distance < 1.0, "{e}");
    }
    // The knocked camera found again, and written into the calibration,
    // to its stated accuracy and within the 0.02 deg the drift issue asks.
    // The markers that held still (the hidden object's in the glass, the
    // two fiducials at the top of the view) join the arm's views: the turn
    // about the optical axis, 0.02-0.03 deg (1-sigma) from the arm's views
    // alone, about 0.003 with them.
    let found = camera["head_cameras_deg"][0][1].as_f64().unwrap();
    let cal = &placement["report"]["calibration"];
    let entry = &cal["head_cameras"][0];
    assert_eq!(entry["name"], "left", "{cal}");
    let sigma: Vec<f64> = (0..3)
        .map(|i| entry["sigma_deg"][i].as_f64().unwrap())
        .collect();
    let total = sigma.iter().map(|s| s * s).sum::<f64>().sqrt();
    assert!(
        found < 3.0 * total && found < 0.02,
        "{found} deg, 1-sigma {sigma:?}"
    );
    assert!(sigma[2] < 0.01, "about the optical axis: {sigma:?}");
    // The hidden object, located through the last epoch's calibration, to
    // its stated accuracy: over a metre of light path and a 60 mm stereo
    // baseline, the found camera's turn (a few thousandths of a degree)
    // moves it by a fraction of a millimetre in depth.
    let object = placement["hidden_object_error_mm"].as_f64().unwrap();
    let sigma = placement["hidden_object_sigma_mm"].as_f64().unwrap();
    assert!(
        object < 3.0 * sigma && sigma < 15.0,
        "{object} mm, 1-sigma {sigma} mm"
    );

    // The recording replayed through the mirror stage: the same epochs.
    let recording = out.join("mirror0/recording.mcap");
    let replayed = dir.path().join("replay");
    pipeline(&[
        "--replay",
        recording.to_str().unwrap(),
        "--kind",
        "detections",
        "--out",
        replayed.to_str().unwrap(),
        "--prefix",
        &unique_prefix("drift_replay"),
    ]);
    let (a, b) = (
        calibrations(&recording),
        calibrations(&replayed.join("recording.mcap")),
    );
    assert!(a.len() > 3);
    assert!(a == b, "the replay's calibrations differ from the run's");
    let states: Vec<_> = a.iter().map(|c| (c.epoch.epoch, c.epoch.state)).collect();
    assert!(
        states.contains(&(1, messages::EpochState::Drifted as u32)),
        "{states:?}"
    );
    assert!(
        states.contains(&(2, messages::EpochState::Drifted as u32)),
        "{states:?}"
    );
    assert_eq!(a.last().unwrap().epoch.epoch, 3);
    // `replay diff` shows the epochs of both, the same.
    let diff = Command::new(stage_binaries().join("replay"))
        .args(["diff", recording.to_str().unwrap()])
        .arg(replayed.join("recording.mcap"))
        .args(["--channels", "calibration"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&diff.stdout);
    assert!(diff.status.success(), "{text}");
    for side in ["A", "B"] {
        assert!(
            text.contains(&format!("epochs {side}: revision"))
                && text.contains("the world changed: the mirror moved from pose")
                && text.contains("the world changed: the camera 0 moved from pose"),
            "{text}"
        );
    }
    assert!(!text.contains("epochs differ"), "{text}");
}
