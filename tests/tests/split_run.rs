//! The pipeline split across two hosts on this machine: two network
//! namespaces joined by a veth pair, each side with shared memory and an
//! iceoryx2 root of its own, the robot's clock a day ahead of the
//! workstation's. From one config, `pipeline --side robot` runs the camera,
//! tracker, arm driver and kinematics, `pipeline --side workstation` the
//! mirror stage and the recorder, each with a bridge, the link mutual TLS
//! with the run's certificates (`pipeline certs`). The split run
//! calibrates as the same run on one host does, nothing of either side is
//! in this host's shared memory, and the recording made on the workstation
//! replays bit for bit.
//!
//! Needs root (network, mount and time namespaces); `MIRROR_SKIP_ROOT_TESTS=1`
//! skips it, saying so.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use nalgebra::Vector3;
use serde_json::Value;
use tests::hosts::{TwoHosts, skip_root_tests};
use tests::report::{assert_plane_near_truth, stage_counter, stage_stats};
use tests::{KillOnDrop, stage_binaries, unique_prefix, wait_exit_showing};

/// A short run: 12 calibration poses, 8 test poses, frames compressed on
/// the link.
const CONFIG: &str = "preset = \"nico\"\nmirrors = [0]\ntrain_poses = 12\ntest_poses = 5\n\
    direct_poses = 3\nmethod = \"joint+kinematics\"\nsource = \"sim\"\nfps = 30.0\n\
    move_ms = 100\ndwell_ms = 250\nseed = 4\nmin_train = 8\n\n[split]\ncompress_frames = \"zstd\"\n";

/// How far the robot's clock is ahead of the workstation's: a day.
const AHEAD_S: i64 = 86_400;

/// The logs at `paths`, each under its name.
fn logs(paths: &[PathBuf]) -> String {
    paths
        .iter()
        .map(|p| {
            format!(
                "--- {}:\n{}",
                p.display(),
                std::fs::read_to_string(p).unwrap_or_default()
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
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

/// A split run of `config` done: its directory and both sides' logs.
struct SplitRun {
    dir: tempfile::TempDir,
    logs: String,
}

impl SplitRun {
    fn out(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    /// Placement 0 of the launcher's report in `OUT/<name>`.
    fn placement(&self, name: &str) -> Value {
        json(&self.out(&format!("{name}/report.json")))["placements"][0].clone()
    }
}

/// How long after the robot side the workstation side is started.
const WORKSTATION_LATER: Duration = Duration::from_secs(3);

/// Runs `config` (written to `DIR/pipeline.toml`) split: the robot side on
/// host 0, its clock a day ahead, the workstation side on host 1; checks
/// that neither side has anything in this host's shared memory while they
/// run and that both exit 0. With `one_host`, first the same config on one
/// host, into `DIR/single`.
fn split_run(config: &str, name: &str, one_host: bool) -> SplitRun {
    // One split run at a time: each is two hosts' pipelines on two cores.
    static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let config_path = dir.path().join("pipeline.toml");
    std::fs::write(&config_path, config).unwrap();
    let config = config_path.to_str().unwrap();
    let pipeline = stage_binaries().join("pipeline");
    let out = |name: &str| dir.path().join(name);

    if one_host {
        let single = Command::new(&pipeline)
            .args(["--config", config, "--no-record", "--report", "json"])
            .args(["--out", out("single").to_str().unwrap()])
            .args(["--prefix", &unique_prefix(&format!("{name}_one"))])
            .output()
            .unwrap();
        assert!(
            single.status.success(),
            "{}",
            String::from_utf8_lossy(&single.stderr)
        );
    }

    let hosts = TwoHosts::new();
    // Mutual TLS with the run's own certificates, as a split run has it
    // by default (`pipeline certs`).
    let endpoint = format!("tls/{}:7447", hosts.addresses[0]);
    let certs = out("certs");
    let made = Command::new(&pipeline)
        .args(["certs", "--out", certs.to_str().unwrap()])
        .args(["--robot-host", &hosts.addresses[0]])
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    let robot_prefix = unique_prefix(&format!("{name}_r"));
    let ws_prefix = unique_prefix(&format!("{name}_w"));
    let side = |k: usize, ahead_s: i64, side: &str, link: &str, prefix: &str| {
        let log = out(&format!("{side}.log"));
        let child = hosts
            .machine(k, ahead_s, &pipeline)
            .args(["--side", side, link, &endpoint, "--config", config])
            .args(["--certs", certs.to_str().unwrap()])
            .args(["--out", out(side).to_str().unwrap(), "--prefix", prefix])
            .args(["--report", "json"])
            .stdout(Stdio::null())
            .stderr(File::create(&log).unwrap())
            .spawn()
            .unwrap();
        (KillOnDrop(child), log)
    };
    let (mut robot, robot_log) = side(0, AHEAD_S, "robot", "--listen", &robot_prefix);
    // The workstation comes up a while after the robot, as two hosts
    // started by hand do: the robot's camera and arm wait for it, so that
    // its recording holds every frame the robot's tracker sees.
    std::thread::sleep(WORKSTATION_LATER);
    let (mut ws, ws_log) = side(1, 0, "workstation", "--connect", &ws_prefix);

    let all_logs = [
        ws_log.clone(),
        robot_log.clone(),
        out("workstation/mirror0/stages.log"),
        out("robot/mirror0/stages.log"),
    ];
    // Once poses are paired, every stage of both sides is up: none of
    // them has anything in this host's shared memory or iceoryx2 root.
    let deadline = Instant::now() + Duration::from_secs(120);
    while !std::fs::read_to_string(&ws_log)
        .unwrap()
        .contains(" 2/20 poses paired")
    {
        assert!(
            Instant::now() < deadline && ws.0.try_wait().unwrap().is_none(),
            "no poses paired on the workstation:\n{}",
            logs(&all_logs)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let prefixes = [robot_prefix.as_str(), ws_prefix.as_str()];
    for shared in ["/dev/shm", "/tmp/iceoryx2/services", "/tmp/iceoryx2/nodes"] {
        let found = entries_with(shared, &prefixes);
        assert!(found.is_empty(), "{shared} on this host holds {found:?}");
    }

    let show_logs = || format!(":\n{}", logs(&all_logs));
    let ws_status = wait_exit_showing(
        &mut ws.0,
        Duration::from_secs(300),
        "the workstation",
        show_logs,
    );
    let robot_status = wait_exit_showing(
        &mut robot.0,
        Duration::from_secs(60),
        "the robot",
        show_logs,
    );
    let logs = logs(&all_logs);
    assert!(ws_status.success() && robot_status.success(), "{logs}");
    SplitRun { dir, logs }
}

/// Nothing the robot sent went missing on the way or was refused, and
/// every topic its stages publish for the workstation arrived.
fn assert_nothing_lost(split: &Value, topics: &[&str]) {
    let c = &split["report"]["counters"];
    assert_eq!(c["joint_states_missed"], 0, "{c}");
    for topic in topics {
        assert_eq!(
            stage_counter(split, "bridge", &format!("lost_{topic}")),
            0,
            "lost {topic}: {}",
            stage_stats(split, "bridge").map_or(&Value::Null, |s| &s["counters"])
        );
        assert!(stage_counter(split, "bridge", &format!("received_{topic}")) > 0);
    }
    assert_eq!(stage_counter(split, "bridge", "refused"), 0);
}

#[test]
fn a_run_split_between_robot_and_workstation_calibrates_as_on_one_host_and_replays() {
    if skip_root_tests() {
        return;
    }
    let run = split_run(CONFIG, "split", true);
    let out = |name: &str| run.out(name);
    let logs = &run.logs;
    let robot_log = out("robot.log");

    // The workstation calibrated as one host does.
    let (one, split) = (&run.placement("single"), &run.placement("workstation"));
    assert_plane_near_truth(one);
    assert_plane_near_truth(split);
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
    assert_nothing_lost(
        split,
        &[
            "frames",
            "detections",
            "joint_state",
            "joint_positions",
            "pose_goal",
        ],
    );
    // The robot side: no mirror stage report, and its bridge sent every
    // topic its stages publish; its progress came back over the link.
    let robot_report = &run.placement("robot");
    assert!(robot_report.get("report").is_none(), "{robot_report}");
    assert!(stage_counter(robot_report, "bridge", "received_samples") > 0);
    assert_eq!(stage_counter(robot_report, "bridge", "dropped_frames"), 0);
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

    // The workstation's recording, replayed on one host: its detections
    // through the mirror stage give the same results bit for bit; its
    // frames through the tracker too, and the same detections. (The
    // workstation stops when its mirror stage is done, while the robot may
    // still stream: the recording can end with a frame whose detection was
    // on its way, which the replay detects, or with a detection whose
    // frame was: at most one more or one fewer at the end.)
    let recording = out("workstation/mirror0/recording.mcap");
    // A frame the recorder's writer had no room for (a machine too busy for
    // it at its lower priority) is missing from the recording: the replay
    // would track from other frames and could not match.
    assert_eq!(
        stage_counter(split, "recorder", "frames_dropped_queue_full"),
        0,
        "the workstation's recording misses frames: {}",
        stage_stats(split, "recorder").map_or(&Value::Null, |s| &s["counters"])
    );
    for kind in ["detections", "frames"] {
        let replayed = out(&format!("replay_{kind}"));
        let replay = Command::new(stage_binaries().join("pipeline"))
            .args(["--replay", recording.to_str().unwrap(), "--kind", kind])
            .args(["--out", replayed.to_str().unwrap(), "--report", "json"])
            .args(["--prefix", &unique_prefix(&format!("split_replay_{kind}"))])
            .output()
            .unwrap();
        assert!(
            replay.status.success(),
            "{}\n{}",
            String::from_utf8_lossy(&replay.stderr),
            std::fs::read_to_string(replayed.join("stages.log")).unwrap_or_default()
        );
        let diff = Command::new(stage_binaries().join("replay"))
            .arg("diff")
            .args([&recording, &replayed.join("recording.mcap")])
            .args(["--json", "--channels"])
            .arg("detections,samples,calibration,predictions,located")
            .output()
            .unwrap();
        let said: Value = serde_json::from_slice(&diff.stdout).unwrap();
        for channel in said["channels"].as_array().unwrap() {
            let (a, b) = (
                channel["count_a"].as_u64().unwrap(),
                channel["count_b"].as_u64().unwrap(),
            );
            // Frames cross at a lower priority than detections: at the end
            // the recording may also hold the last detection without its
            // frame (one fewer replayed). Every detection both have is
            // the same either way.
            let tail = if kind == "frames" && channel["channel"] == "detections" {
                -1..=1
            } else {
                0..=0
            };
            assert!(
                channel["first_difference"].is_null() && tail.contains(&(b as i64 - a as i64)),
                "replay of the {kind}: {channel}"
            );
        }
        let counts: Vec<String> = said["channels"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| format!("{} {}/{}", c["channel"], c["count_a"], c["count_b"]))
            .collect();
        eprintln!("replay of the {kind}: {}", counts.join(", "));
    }
}

/// The tracker offloaded to the workstation (`[split] tracker =
/// "workstation"`): every frame crosses, the detections are made there
/// from the robot's frames (their stamps moved by the day) and paired with
/// the robot's joint states; the calibration is as good, nothing is lost,
/// and the detections go back to the robot.
#[test]
fn with_the_tracker_offloaded_the_workstation_detects_and_calibrates() {
    if skip_root_tests() {
        return;
    }
    let config = CONFIG.replace("[split]\n", "[split]\ntracker = \"workstation\"\n");
    let run = split_run(&config, "offload", false);
    let split = &run.placement("workstation");
    assert_plane_near_truth(split);
    let report = &split["report"];
    assert_eq!(
        (&report["train_samples"], &report["test_samples"]),
        (&12.into(), &8.into()),
        "{}",
        run.logs
    );
    assert_nothing_lost(
        split,
        &["frames", "joint_state", "joint_positions", "pose_goal"],
    );
    assert!(
        stage_stats(split, "tracker_proc").is_some(),
        "no tracker on the workstation: {split}"
    );
    let robot = &run.placement("robot");
    assert!(stage_counter(robot, "bridge", "received_detections") > 0);
    eprintln!(
        "offloaded: plane {:.3} deg / {:.2} mm off the truth",
        split["plane_angle_deg"].as_f64().unwrap(),
        split["plane_distance_mm"].as_f64().unwrap()
    );
}
