//! The arm driver contract: `kinematics_proc` owns the plan and follows any
//! driver that publishes `joint_positions` and moves to `pose_goal`s. The
//! Python SDK's layouts match the Rust types; the example Python driver
//! stands in for the simulated arm in a whole run; a driver with the wrong
//! joints or none at all is a clear one-line error.

use std::mem::{align_of, offset_of, size_of};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use messages::topics;
use messages::{JointPositions, PoseGoal, now_ns};
use runtime::Bus;
use tests::python::python_with_driver_sdk;
use tests::{KillOnDrop, stage_binaries, unique_prefix};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn the_python_sdk_layouts_are_the_rust_layouts() {
    let out = Command::new(python_with_driver_sdk())
        .args([
            "-c",
            "import json, mirror_driver as m; print(json.dumps({t.type_name(): m.layout(t) for t in (m.JointPositions, m.PoseGoal)}))",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let py: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let rust = serde_json::json!({
        "mirror.JointPositions.v1": {
            "type_name": topics::TopicId::JointPositions.layout().type_name,
            "size": size_of::<JointPositions>(),
            "align": align_of::<JointPositions>(),
            "fields": {
                "seq": offset_of!(JointPositions, seq),
                "stamp_ns": offset_of!(JointPositions, stamp_ns),
                "dof": offset_of!(JointPositions, dof),
                "reserved": offset_of!(JointPositions, reserved),
                "q": offset_of!(JointPositions, q),
            },
        },
        "mirror.PoseGoal.v1": {
            "type_name": topics::TopicId::PoseGoal.layout().type_name,
            "size": size_of::<PoseGoal>(),
            "align": align_of::<PoseGoal>(),
            "fields": {
                "seq": offset_of!(PoseGoal, seq),
                "stamp_ns": offset_of!(PoseGoal, stamp_ns),
                "pose": offset_of!(PoseGoal, pose),
                "role": offset_of!(PoseGoal, role),
                "dof": offset_of!(PoseGoal, dof),
                "flags": offset_of!(PoseGoal, flags),
                "reserved": offset_of!(PoseGoal, reserved),
                "q": offset_of!(PoseGoal, q),
            },
        },
    });
    assert_eq!(py, rust);
}

/// Writes the simulated robot's rig and a two-pose plan into `dir`.
fn rig_and_plan(dir: &Path) -> (PathBuf, PathBuf) {
    let rig = dir.join("rig.toml");
    formats::rig::write(&rig, &geometry::sim::nico_scene().rig).unwrap();
    let plan = dir.join("plan.csv");
    std::fs::write(
        &plan,
        "pose,role,q0,q1,q2,q3\n0,train,1.0,0.0,0.0,0.0\n1,train,1.2,0.1,0.0,0.0\n",
    )
    .unwrap();
    (rig, plan)
}

/// Runs `kinematics_proc` on `prefix` while `driver` plays the arm; returns
/// its exit status and stderr.
fn kinematics_with(
    prefix: &str,
    dir: &Path,
    mut driver: impl FnMut(&Bus) -> bool,
) -> (bool, String) {
    let (rig, plan) = rig_and_plan(dir);
    let bus = Bus::new(prefix, "test_driver").unwrap();
    let child = Command::new(stage_binaries().join("kinematics_proc"))
        .args([
            "--prefix",
            prefix,
            "--rig",
            rig.to_str().unwrap(),
            "--plan",
            plan.to_str().unwrap(),
        ])
        .args(["--silent-ms", "1000", "--dwell-ms", "50"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut child = KillOnDrop(child);
    let started = Instant::now();
    while child.0.try_wait().unwrap().is_none() {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "kinematics_proc did not stop"
        );
        if !driver(&bus) {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let status = child.0.wait().unwrap();
    let mut stderr = String::new();
    std::io::Read::read_to_string(child.0.stderr.as_mut().unwrap(), &mut stderr).unwrap();
    (status.success(), stderr)
}

fn last_error(stderr: &str) -> &str {
    stderr.lines().rfind(|l| l.contains("error")).unwrap_or("")
}

#[test]
fn a_driver_with_the_wrong_joints_or_none_is_a_one_line_error() {
    let dir = tempfile::tempdir().unwrap();
    // Six joints for a four-joint arm: every reading is refused, counted, and named.
    let prefix = unique_prefix("six_joints");
    let mut ports = None;
    let (ok, stderr) = kinematics_with(&prefix, dir.path(), |bus| {
        let (positions, _goals) = ports.get_or_insert_with(|| {
            (
                bus.publisher::<topics::JointPositions>().unwrap(),
                bus.subscriber::<topics::PoseGoal>().unwrap(),
            )
        });
        positions
            .send(JointPositions {
                stamp_ns: now_ns(),
                dof: 6,
                ..Default::default()
            })
            .unwrap();
        true
    });
    let line = last_error(&stderr);
    assert!(!ok, "{stderr}");
    assert!(
        line.contains("the arm driver sent no usable joint positions for 1.0 s")
            && line.contains("the last because: 6 joints, the arm has 4"),
        "{stderr}"
    );
    assert!(
        stderr.contains("dropping a joint positions message"),
        "{stderr}"
    );
    // A driver that listens for goals but never answers.
    let prefix = unique_prefix("silent");
    let mut goals = None;
    let (ok, stderr) = kinematics_with(&prefix, dir.path(), |bus| {
        goals.get_or_insert_with(|| bus.subscriber::<topics::PoseGoal>().unwrap());
        true
    });
    assert!(!ok, "{stderr}");
    assert!(
        last_error(&stderr)
            .contains("sent no usable joint positions for 1.0 s (0 received, 0 rejected)"),
        "{stderr}"
    );
}

/// The example Python driver (`python/examples/sim_arm.py`, on the SDK)
/// plays the arm of a whole run in place of the built-in one, and the
/// calibration completes: plane within 0.5 deg and 5 mm of the truth.
#[test]
fn the_python_example_driver_stands_in_for_the_arm() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("pipeline.toml");
    std::fs::write(
        &config,
        "preset = \"nico\"\nmirrors = [0]\ntrain_poses = 10\ntest_poses = 4\ndirect_poses = 2\n\
         method = \"joint+kinematics\"\nsource = \"sim\"\nfps = 30.0\nmove_ms = 300\ndwell_ms = 250\n\
         seed = 5\nmin_train = 8\n",
    )
    .unwrap();
    let driver = format!(
        "{} {}",
        python_with_driver_sdk().display(),
        repo().join("python/examples/sim_arm.py").display()
    );
    let out = dir.path().join("out");
    let output = Command::new(stage_binaries().join("pipeline"))
        .args([
            "--config",
            config.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .args([
            "--prefix",
            &unique_prefix("python_driver"),
            "--no-record",
            "--report",
            "json",
        ])
        .args(["--arm-driver", &driver])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let placement = &report["placements"][0];
    let (angle, distance) = (
        placement["plane_angle_deg"].as_f64().unwrap(),
        placement["plane_distance_mm"].as_f64().unwrap(),
    );
    assert!(
        angle < 0.5 && distance < 5.0,
        "plane off by {angle} deg / {distance} mm"
    );
    assert!(
        placement["report"]["train_samples"].as_u64().unwrap() >= 8,
        "{placement}"
    );
    let log = std::fs::read_to_string(out.join("mirror0/stages.log")).unwrap();
    assert!(!log.contains("Traceback"), "{log}");
    let settle = &placement["stages"]["kinematics_proc"]["latency"]["goal_to_settled"];
    eprintln!("python driver: plane {angle:.4} deg / {distance:.3} mm; goal to settled {settle}");
}
