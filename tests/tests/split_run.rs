//! The pipeline split across two hosts on this machine: two network
//! namespaces joined by a veth pair, each side with shared memory and an
//! iceoryx2 root of its own, the robot's clock a day ahead of the
//! workstation's. From one config, `pipeline --side robot` runs the camera,
//! tracker, arm driver and kinematics, `pipeline --side workstation` the
//! mirror stage and the recorder, each with a bridge. The split run
//! calibrates as the same run on one host does, nothing of either side is
//! in this host's shared memory, and the recording made on the workstation
//! replays bit for bit.
//!
//! Needs root (network, mount and time namespaces); `MIRROR_SKIP_ROOT_TESTS=1`
//! skips it, saying so.

use std::fs::File;
use std::path::Path;
use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use nalgebra::Vector3;
use serde_json::Value;
use tests::hosts::{TwoHosts, skip_root_tests};
use tests::{KillOnDrop, stage_binaries, unique_prefix};

/// A short run: 12 calibration poses, 8 test poses, frames compressed on
/// the link.
const CONFIG: &str = "preset = \"nico\"\nmirrors = [0]\ntrain_poses = 12\ntest_poses = 5\n\
    direct_poses = 3\nmethod = \"joint+kinematics\"\nsource = \"sim\"\nfps = 30.0\n\
    move_ms = 100\ndwell_ms = 250\nseed = 4\nmin_train = 8\n\n[split]\ncompress_frames = \"zstd\"\n";

/// How far the robot's clock is ahead of the workstation's: a day.
const AHEAD_S: i64 = 86_400;

/// Waits for `child` to exit, at most `within`.
fn wait(child: &mut KillOnDrop, within: Duration, what: &str, log: &Path) -> ExitStatus {
    let deadline = Instant::now() + within;
    loop {
        if let Some(status) = child.0.try_wait().unwrap() {
            return status;
        }
        assert!(
            Instant::now() < deadline,
            "{what} did not finish in {} s:\n{}",
            within.as_secs(),
            std::fs::read_to_string(log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap())
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The plane of a report's calibration: unit normal and distance.
fn plane(report: &Value) -> (Vector3<f64>, f64) {
    let p = &report["calibration"]["plane"];
    let n: Vec<f64> = serde_json::from_value(p["normal"].clone()).unwrap();
    (
        Vector3::new(n[0], n[1], n[2]),
        p["distance"].as_f64().unwrap(),
    )
}

/// A counter of a stage's stats in a placement of a launcher's report.
fn counter(placement: &Value, stage: &str, name: &str) -> u64 {
    let stage = placement["stages"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["stage"] == stage)
        .unwrap_or_else(|| panic!("no {stage} stats in {placement}"));
    stage["counters"][name]
        .as_u64()
        .unwrap_or_else(|| panic!("no {name} in {stage}"))
}

/// Names of `dir`'s entries that contain one of `prefixes`.
fn entries_with(dir: &str, prefixes: &[&str]) -> Vec<String> {
    std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| prefixes.iter().any(|p| n.contains(p)))
                .collect()
        })
        .unwrap_or_default()
}

#[test]
fn a_run_split_between_robot_and_workstation_calibrates_as_on_one_host_and_replays() {
    if skip_root_tests() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("pipeline.toml");
    std::fs::write(&config, CONFIG).unwrap();
    let config = config.to_str().unwrap();
    let pipeline = stage_binaries().join("pipeline");
    let out = |name: &str| dir.path().join(name);

    // The same run on one host.
    let single = Command::new(&pipeline)
        .args(["--config", config, "--no-record", "--report", "json"])
        .args(["--out", out("single").to_str().unwrap()])
        .args(["--prefix", &unique_prefix("split_single")])
        .output()
        .unwrap();
    assert!(
        single.status.success(),
        "{}",
        String::from_utf8_lossy(&single.stderr)
    );

    let hosts = TwoHosts::new();
    let endpoint = format!("tcp/{}:7447", hosts.addresses[0]);
    let (robot_prefix, ws_prefix) = (unique_prefix("split_r"), unique_prefix("split_w"));
    let side = |k: usize, ahead_s: i64, side: &str, link: &str, prefix: &str| {
        let log = out(&format!("{side}.log"));
        let child = hosts
            .machine(k, ahead_s, &pipeline)
            .args(["--side", side, link, &endpoint, "--config", config])
            .args(["--out", out(side).to_str().unwrap(), "--prefix", prefix])
            .args(["--report", "json"])
            .stdout(Stdio::null())
            .stderr(File::create(&log).unwrap())
            .spawn()
            .unwrap();
        (KillOnDrop(child), log)
    };
    let (mut robot, robot_log) = side(0, AHEAD_S, "robot", "--listen", &robot_prefix);
    let (mut ws, ws_log) = side(1, 0, "workstation", "--connect", &ws_prefix);

    // Once poses are paired, every stage of both sides is up: none of
    // them has anything in this host's shared memory or iceoryx2 root.
    let deadline = Instant::now() + Duration::from_secs(120);
    while !std::fs::read_to_string(&ws_log)
        .unwrap()
        .contains(" 2/20 poses paired")
    {
        assert!(
            Instant::now() < deadline && ws.0.try_wait().unwrap().is_none(),
            "no poses paired on the workstation:\n{}\nrobot:\n{}",
            std::fs::read_to_string(&ws_log).unwrap(),
            std::fs::read_to_string(&robot_log).unwrap()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let prefixes = [robot_prefix.as_str(), ws_prefix.as_str()];
    for shared in ["/dev/shm", "/tmp/iceoryx2/services", "/tmp/iceoryx2/nodes"] {
        let found = entries_with(shared, &prefixes);
        assert!(found.is_empty(), "{shared} on this host holds {found:?}");
    }

    let ws_status = wait(
        &mut ws,
        Duration::from_secs(300),
        "the workstation",
        &ws_log,
    );
    let robot_status = wait(&mut robot, Duration::from_secs(60), "the robot", &robot_log);
    let logs = format!(
        "workstation:\n{}\nrobot:\n{}",
        std::fs::read_to_string(&ws_log).unwrap(),
        std::fs::read_to_string(&robot_log).unwrap()
    );
    assert!(ws_status.success() && robot_status.success(), "{logs}");

    // The workstation calibrated as one host does.
    let one = &json(&out("single/report.json"))["placements"][0];
    let split = &json(&out("workstation/report.json"))["placements"][0];
    for placement in [one, split] {
        let (angle, distance) = (
            placement["plane_angle_deg"].as_f64().unwrap(),
            placement["plane_distance_mm"].as_f64().unwrap(),
        );
        assert!(
            angle < 0.5 && distance < 5.0,
            "plane off the truth by {angle} deg / {distance} mm"
        );
    }
    let (one_report, split_report) = (&one["report"], &split["report"]);
    let ((n1, d1), (n2, d2)) = (plane(one_report), plane(split_report));
    let apart_deg = n1.angle(&n2).to_degrees();
    let apart_mm = (d1 - d2).abs();
    eprintln!(
        "one host: {} train / {} test samples, plane {:.3} deg / {:.2} mm off the truth; \
         split: {} / {}, {:.3} deg / {:.2} mm; the two planes {apart_deg:.3} deg / {apart_mm:.2} mm apart",
        one_report["train_samples"],
        one_report["test_samples"],
        one["plane_angle_deg"].as_f64().unwrap(),
        one["plane_distance_mm"].as_f64().unwrap(),
        split_report["train_samples"],
        split_report["test_samples"],
        split["plane_angle_deg"].as_f64().unwrap(),
        split["plane_distance_mm"].as_f64().unwrap(),
    );
    assert_eq!(
        split_report["train_samples"], one_report["train_samples"],
        "{logs}"
    );
    assert_eq!(split_report["test_samples"], one_report["test_samples"]);
    assert!(
        apart_deg < 0.1 && apart_mm < 1.5,
        "the split run's plane is {apart_deg} deg / {apart_mm} mm from one host's"
    );
    // Nothing the robot sent went missing on the way or was refused.
    let c = &split_report["counters"];
    assert_eq!(c["joint_states_missed"], 0, "{c}");
    assert_eq!(c["detections_missed"], 0, "{c}");
    for topic in [
        "frames",
        "detections",
        "joint_state",
        "joint_positions",
        "pose_goal",
    ] {
        assert_eq!(counter(split, "bridge", &format!("lost_{topic}")), 0);
        assert!(counter(split, "bridge", &format!("received_{topic}")) > 0);
    }
    assert_eq!(counter(split, "bridge", "refused"), 0);
    // The robot side: no mirror stage report, and its bridge sent every
    // topic its stages publish; its progress came back over the link.
    let robot_report = &json(&out("robot/report.json"))["placements"][0];
    assert!(robot_report.get("report").is_none(), "{robot_report}");
    assert!(counter(robot_report, "bridge", "received_samples") > 0);
    assert_eq!(counter(robot_report, "bridge", "dropped_frames"), 0);
    assert!(
        std::fs::read_to_string(&robot_log)
            .unwrap()
            .contains("mirror 0: 20/20 poses paired"),
        "{logs}"
    );
    // The workstation moved the robot's stamps by a day.
    let stages_log = std::fs::read_to_string(out("workstation/mirror0/stages.log")).unwrap();
    let ahead: f64 = stages_log
        .lines()
        .find(|l| l.contains("clock of a new sender"))
        .and_then(|l| l.split("ahead_s=").nth(1)?.split(' ').next()?.parse().ok())
        .unwrap_or_else(|| panic!("no clock offset in the log:\n{stages_log}"));
    assert!((ahead - AHEAD_S as f64).abs() < 0.005, "ahead {ahead} s");

    // The workstation's recording, replayed on one host (frames through the
    // tracker and the mirror stage), gives the same detections and results.
    let recording = out("workstation/mirror0/recording.mcap");
    let replay = Command::new(&pipeline)
        .args(["--replay", recording.to_str().unwrap(), "--kind", "frames"])
        .args(["--out", out("replay").to_str().unwrap()])
        .args([
            "--prefix",
            &unique_prefix("split_replay"),
            "--report",
            "json",
        ])
        .output()
        .unwrap();
    assert!(
        replay.status.success(),
        "{}",
        String::from_utf8_lossy(&replay.stderr)
    );
    let diff = Command::new(stage_binaries().join("replay"))
        .arg("diff")
        .args([&recording, &out("replay/recording.mcap")])
        .args([
            "--channels",
            "detections,samples,calibration,predictions,located",
        ])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&diff.stdout);
    assert_eq!(diff.status.code(), Some(0), "{said}");
    assert!(said.contains("identical: 5 channels"), "{said}");
    eprintln!("{said}");
}
