//! Faults on a running pipeline: stages killed with SIGKILL and restarted by
//! the launcher, a stage started twice, a rogue publisher sending malformed
//! messages on every input topic, and the shared memory left by a crash.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use messages::topics::TopicId;
use messages::{
    CameraMarkers, Encoding, FrameHeader, JointPositions, JointState, Marker, MirrorSample, Phase,
    PoseGoal, Role, StereoDetections, now_ns, topics,
};
use mirror_proc::calibrate::Method;
use runtime::Bus;
use serde_json::Value;
use tests::report::{assert_plane_near_truth, stage_counter_summed_over_processes};
use tests::{KillOnDrop, stage_binaries, unique_prefix};

use super::wait_for_line;

/// The launcher on mirror 0 (12 calibration, 5 + 3 test poses) with its
/// stderr lines delivered to the caller as they come.
struct Launcher {
    child: KillOnDrop,
    lines: mpsc::Receiver<String>,
    out: PathBuf,
    prefix: String,
    stderr: Vec<String>,
    /// Poses paired, as the launcher last reported.
    paired: usize,
}

impl Launcher {
    fn start(name: &str, record: bool) -> Self {
        let dir = tempfile::tempdir().unwrap().keep();
        let config = dir.join("pipeline.toml");
        std::fs::write(
            &config,
            "preset = \"nico\"\nmirrors = [0]\ntrain_poses = 12\ntest_poses = 5\ndirect_poses = 3\n\
             method = \"joint+kinematics\"\nsource = \"sim\"\nfps = 30.0\nmove_ms = 100\ndwell_ms = 250\n\
             seed = 4\nmin_train = 8\n",
        )
        .unwrap();
        let out = dir.join("out");
        let prefix = unique_prefix(name);
        let mut command = Command::new(stage_binaries().join("pipeline"));
        command
            .args(["--config", config.to_str().unwrap()])
            .args(["--out", out.to_str().unwrap()])
            .args(["--prefix", &prefix, "--report", "json"]);
        if !record {
            command.arg("--no-record");
        }
        let mut child = command
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let stderr = child.stderr.take().unwrap();
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Self {
            child: KillOnDrop(child),
            lines,
            out,
            // The launcher's prefix for placement 0.
            prefix: format!("{prefix}_m0"),
            stderr: Vec::new(),
            paired: 0,
        }
    }

    /// Waits until the launcher reports at least `n` poses paired.
    fn wait_paired(&mut self, n: usize) {
        self.wait_progress(&format!("{n} poses paired"), |paired, _| paired >= n);
    }

    /// Waits until the launcher's progress line (poses paired, calibration
    /// revision) satisfies `done`.
    fn wait_progress(&mut self, what: &str, done: impl Fn(usize, u64) -> bool) {
        let deadline = Instant::now() + Duration::from_secs(120);
        loop {
            let line = self
                .lines
                .recv_timeout(deadline.saturating_duration_since(Instant::now()))
                .unwrap_or_else(|_| panic!("never {what}: {:?}", self.stderr));
            // "mirror 0: 3/20 poses paired, calibration revision 2 (train RMS ...)"
            let progress = line
                .strip_prefix("mirror 0: ")
                .filter(|rest| rest.contains(" poses paired"))
                .and_then(|rest| {
                    let (paired, rest) = rest.split_once('/')?;
                    let revision = rest.split("calibration revision ").nth(1)?;
                    let revision = revision.split_whitespace().next()?;
                    Some((paired.parse::<usize>().ok()?, revision.parse::<u64>().ok()?))
                });
            self.stderr.push(line);
            if let Some((paired, revision)) = progress {
                self.paired = paired;
                if done(paired, revision) {
                    return;
                }
            }
        }
    }

    /// Waits for the launcher to finish; returns its placement report.
    fn finish(mut self) -> (Value, Vec<String>) {
        let status = self.child.0.wait().unwrap();
        self.stderr.extend(self.lines.try_iter());
        let mut stdout = String::new();
        std::io::Read::read_to_string(self.child.0.stdout.as_mut().unwrap(), &mut stdout).unwrap();
        assert!(status.success(), "pipeline failed: {:?}", self.stderr);
        let report: Value = serde_json::from_str(&stdout).expect("a JSON report");
        (report["placements"][0].clone(), self.stderr)
    }
}

/// The pid of stage `name` running on `prefix`, from /proc.
fn pid_of(name: &str, prefix: &str) -> Option<i32> {
    std::fs::read_dir("/proc")
        .ok()?
        .flatten()
        .find_map(|entry| {
            let pid: i32 = entry.file_name().to_str()?.parse().ok()?;
            let cmdline = std::fs::read(entry.path().join("cmdline")).ok()?;
            let args: Vec<&[u8]> = cmdline.split(|&b| b == 0).collect();
            let is_stage = args
                .first()
                .is_some_and(|a| Path::new(std::str::from_utf8(a).unwrap_or("")).ends_with(name));
            let on_prefix = args
                .windows(2)
                .any(|w| w[0] == b"--prefix" && w[1] == prefix.as_bytes());
            (is_stage && on_prefix).then_some(pid)
        })
}

#[allow(unsafe_code)]
fn kill9(name: &str, prefix: &str) {
    let pid = pid_of(name, prefix).unwrap_or_else(|| panic!("{name} is not running"));
    // SAFETY: plain kill(2) on a pid we just read.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGKILL) }, 0);
}

/// Each stage killed with SIGKILL in turn mid-run: the launcher restarts it,
/// the new process reattaches to the services, and the calibration still
/// completes. A second tracker started on the same pipeline changes nothing
/// but the duplicate count.
#[test]
fn stages_killed_mid_run_are_restarted_and_the_calibration_completes() {
    let mut run = Launcher::start("kill", false);
    let prefix = run.prefix.clone();
    run.wait_paired(2);
    kill9("tracker_proc", &prefix);
    run.wait_paired(4);
    kill9("camera_proc", &prefix);
    run.wait_paired(6);
    // The mirror stage resumes from its journal.
    kill9("mirror_proc", &prefix);
    run.wait_paired(8);
    // The arm's driver takes up its plan after the last pose reached.
    kill9("kinematics_proc", &prefix);
    // And a tracker started twice.
    let log = std::fs::File::create(run.out.join("second_tracker.log")).unwrap();
    let _second = KillOnDrop(
        Command::new(stage_binaries().join("tracker_proc"))
            .args(["run", "--prefix", &prefix])
            .stderr(log)
            .spawn()
            .unwrap(),
    );
    let stages_log_path = run.out.join("mirror0/stages.log");
    let (placement, stderr) = run.finish();
    for stage in [
        "tracker_proc",
        "camera_proc",
        "mirror_proc",
        "kinematics_proc",
    ] {
        assert!(
            stderr
                .iter()
                .any(|l| l.contains(&format!("{stage} exited")) && l.contains("restarting")),
            "{stage} not restarted: {stderr:?}"
        );
    }
    assert_eq!(placement["restarts"], 4, "{placement}");
    assert_plane_near_truth(&placement);
    let live = &placement["report"];
    let c = &live["counters"];
    // Each of the four kills may cost the pose being sampled when it came
    // (the stage's restart outlasts a 250 ms dwell on a busy machine), no more.
    assert!(
        live["train_samples"].as_u64().unwrap() >= 12 - 4,
        "calibration poses: {live}"
    );
    assert_eq!(
        c["poses_repeated"], 0,
        "a resumed plan repeats no pose: {c}"
    );
    assert!(c["source_restarts"].as_u64().unwrap() >= 1, "{c}");
    assert!(
        c["joint_states_missed"].as_u64().unwrap() > 0,
        "the restarted mirror stage missed the joint states before it: {c}"
    );
    assert!(
        c["rejected"].as_u64().unwrap() > 0,
        "the second tracker's duplicates: {c}"
    );
    let log = std::fs::read_to_string(stages_log_path).unwrap();
    assert!(log.contains("repeats or goes back"), "no duplicate warning");
    eprintln!(
        "killed 4 stages, restarts {}; samples {} train / {} test; counters {c}; plane {} deg",
        placement["restarts"],
        live["train_samples"],
        live["test_samples"],
        placement["plane_angle_deg"]
    );
}

/// The mirror stage killed twice, after its third calibration and after the
/// last calibration pose: each restart resumes from its journal. The final
/// calibration is the one computed offline from the journaled samples, bit
/// for bit, and every training sample the stage ever published (as the
/// recording saw them) is in the journal and in the calibration.
#[test]
fn a_mirror_stage_killed_twice_resumes_from_its_journal_and_loses_nothing() {
    let mut run = Launcher::start("journal", true);
    let prefix = run.prefix.clone();
    run.wait_progress("a third calibration", |_, revision| revision >= 3);
    let paired = run.paired;
    kill9("mirror_proc", &prefix);
    let killed = Instant::now();
    run.wait_paired(paired + 1);
    let to_next_sample = killed.elapsed();
    // The 12 calibration poses come first in the plan.
    run.wait_paired(12);
    kill9("mirror_proc", &prefix);
    let dir = run.out.join("mirror0");
    let (placement, stderr) = run.finish();
    assert_eq!(placement["restarts"], 2, "{stderr:?}");
    let recovered = &placement["report"]["recovered"];
    assert!(recovered["revision"].as_u64().unwrap() >= 3, "{recovered}");
    assert_eq!(recovered["calibration_reproduced"], true, "{recovered}");

    let journal = runtime::journal::read(&dir.join("journal.mcap")).unwrap();
    let journaled: Vec<MirrorSample> = journal.messages::<topics::Samples>().collect();
    let train: Vec<_> = journaled
        .iter()
        .filter(|s| s.role == Role::Train as u32)
        .map(MirrorSample::to_sample)
        .collect();
    let rig = formats::rig::read(dir.join("rig.toml")).unwrap();
    let offline = mirror_proc::calibrate::calibrate(&rig, &train, Method::JointKinematics)
        .unwrap()
        .to_file(&rig);
    // JSON numbers compare as f64, exactly: bit for bit.
    let live = placement["report"]["calibration"].clone();
    assert_eq!(
        live,
        serde_json::to_value(&offline).unwrap(),
        "the final calibration is not the journaled samples' calibration"
    );
    assert_eq!(live["samples"].as_u64().unwrap() as usize, train.len());

    let recording = recorder::reader::Recording::open(dir.join("recording.mcap")).unwrap();
    let published = recording.lossless_by_topic().unwrap();
    let published: Vec<MirrorSample> = published[&TopicId::Samples]
        .iter()
        .map(|b| bytemuck::pod_read_unaligned(b))
        .collect();
    for s in published.iter().filter(|s| s.role == Role::Train as u32) {
        assert!(
            journaled.contains(s),
            "training sample of pose {} published but not journaled",
            s.pose
        );
    }
    assert!(train.len() >= 10, "{} calibration samples", train.len());
    eprintln!(
        "mirror stage killed twice: resumed at revision {}, {} samples journaled ({} training), \
         final calibration equals the offline one; journal dropped {}; first sample {:.0} ms \
         after the first kill",
        recovered["revision"],
        journaled.len(),
        train.len(),
        recovered["dropped"],
        to_next_sample.as_secs_f64() * 1e3
    );
}

/// The stage that owns the pose plan killed mid-run: the restarted one takes
/// up the plan after the last pose the arm settled at, so no pose is held
/// twice, and the plan completes.
#[test]
fn a_killed_kinematics_stage_resumes_its_plan_and_repeats_no_pose() {
    let mut run = Launcher::start("arm_journal", true);
    let prefix = run.prefix.clone();
    run.wait_paired(4);
    kill9("kinematics_proc", &prefix);
    let dir = run.out.join("mirror0");
    let (placement, stderr) = run.finish();
    assert_eq!(placement["restarts"], 1, "{stderr:?}");
    let recording = recorder::reader::Recording::open(dir.join("recording.mcap")).unwrap();
    let joints: Vec<JointState> = recording.lossless_by_topic().unwrap()[&TopicId::JointState]
        .iter()
        .map(|b| bytemuck::pod_read_unaligned(b))
        .collect();
    // The poses held, in the order they were held: each once.
    let mut held: Vec<u64> = Vec::new();
    for js in joints.iter().filter(|js| js.phase == Phase::Settled as u32) {
        if held.last() != Some(&js.pose) {
            assert!(
                !held.contains(&js.pose),
                "pose {} held twice: {held:?}",
                js.pose
            );
            held.push(js.pose);
        }
    }
    let plan = std::fs::read_to_string(dir.join("plan.csv")).unwrap();
    let planned: Vec<u64> = plan
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(held.last(), planned.last(), "the plan did not complete");
    assert!(joints.iter().any(|js| js.phase == Phase::Done as u32));
    assert!(
        held.len() + 1 >= planned.len(),
        "at most the pose being moved to when the driver died is lost: held {held:?} of {planned:?}"
    );
    let c = &placement["report"]["counters"];
    assert_eq!(c["poses_repeated"], 0, "{c}");
    assert!(c["source_restarts"].as_u64().unwrap() >= 1, "{c}");
    eprintln!(
        "arm driver killed: held {} of {} poses, none twice; {} samples",
        held.len(),
        planned.len(),
        placement["report"]["train_samples"].as_u64().unwrap()
            + placement["report"]["test_samples"].as_u64().unwrap()
    );
}

/// A run that ends without a calibration is a failed run: the launcher
/// writes its report, then exits non-zero with the reason in one line.
#[test]
fn a_run_without_a_calibration_exits_non_zero_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("pipeline.toml");
    std::fs::write(
        &config,
        "preset = \"nico\"\nmirrors = [0]\ntrain_poses = 3\ntest_poses = 1\ndirect_poses = 0\n\
         method = \"joint\"\nsource = \"sim\"\nfps = 30.0\nmove_ms = 100\ndwell_ms = 250\n\
         seed = 4\nmin_train = 8\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let output = Command::new(stage_binaries().join("pipeline"))
        .args(["--config", config.to_str().unwrap()])
        .args(["--out", out.to_str().unwrap()])
        .args(["--prefix", &unique_prefix("uncalibrated"), "--no-record"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    let last = stderr.lines().last().unwrap();
    assert!(
        last.starts_with("pipeline: error: mirror 0: no calibration: ")
            && last.contains("3 of the 8 calibration samples"),
        "{stderr}"
    );
    assert!(out.join("report.json").exists(), "no report");
}

/// The launcher itself killed with SIGKILL: its stages stop too (none is
/// left running on the machine) and the recording is finished, readable
/// to its end.
#[test]
fn a_killed_launcher_takes_its_stages_down_and_the_recording_is_finished() {
    let mut run = Launcher::start("launcher", true);
    let prefix = run.prefix.clone();
    run.wait_paired(2);
    let stages = [
        "camera_proc",
        "tracker_proc",
        "kinematics_proc",
        "sim_arm",
        "mirror_proc",
        "recorder",
    ];
    for stage in stages {
        assert!(pid_of(stage, &prefix).is_some(), "{stage} not running");
    }
    run.child.0.kill().unwrap();
    run.child.0.wait().unwrap();
    let started = Instant::now();
    while let Some(stage) = stages.iter().find(|s| pid_of(s, &prefix).is_some()) {
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "{stage} still runs after the launcher was killed"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let recording =
        recorder::reader::Recording::open(run.out.join("mirror0/recording.mcap")).unwrap();
    let damage = &recording.contents().damage;
    assert!(
        damage.is_none(),
        "the recording was not finished: {damage:?}"
    );
}

/// What a rogue publisher sends, per burst.
const BURSTS: u64 = 4;

/// Publishes malformed messages of every kind on `prefix`'s input topics:
/// frames through iceoryx2 directly (sizes the `Bus` would not let through),
/// joint states, joint positions, pose goals and detections through the `Bus`.
fn rogue(prefix: &str) {
    let bus = Bus::new(prefix, "rogue").unwrap();
    let joints = bus.publisher::<topics::JointState>().unwrap();
    let positions = bus.publisher::<topics::JointPositions>().unwrap();
    let goals = bus.publisher::<topics::PoseGoal>().unwrap();
    let detections = bus.publisher::<topics::Detections>().unwrap();
    let node = NodeBuilder::new().create::<ipc::Service>().unwrap();
    let name = |s: String| ServiceName::new(&s).unwrap();
    let frames = node
        .service_builder(&name(format!("mirror/{prefix}/frames")))
        .publish_subscribe::<[u8]>()
        .user_header::<FrameHeader>()
        .open()
        .unwrap();
    let frame_publisher = frames
        .publisher_builder()
        .initial_max_slice_len(2 * 640 * 480)
        .create()
        .unwrap();
    let frame_event = node
        .service_builder(&name(format!("mirror/{prefix}/frames/event")))
        .event()
        .open()
        .unwrap()
        .notifier_builder()
        .create()
        .unwrap();
    let send_frame = |header: FrameHeader, len: usize| {
        let mut sample = frame_publisher.loan_slice(len).unwrap();
        *sample.user_header_mut() = header;
        sample.send().unwrap();
        frame_event.notify().unwrap();
        // The tracker keeps 8 frames; spaced out, none is overwritten
        // before it is looked at.
        std::thread::sleep(Duration::from_millis(30));
    };
    let good = |stamp_ns| FrameHeader {
        seq: 0,
        stamp_ns,
        published_ns: now_ns(),
        width: 640,
        height: 480,
        stride: 640,
        encoding: Encoding::Mono8 as u32,
    };
    let state = |stamp_ns| JointState {
        stamp_ns,
        dof: 4,
        phase: Phase::Moving as u32,
        ..Default::default()
    };
    let marker = |id, mirrored, x| {
        let mut c = CameraMarkers::default();
        c.push(Marker {
            id,
            mirrored,
            corners: [x; 8],
            center: [x, x],
        });
        c
    };
    let detection = |stamp_ns, cameras| StereoDetections {
        seq: 0,
        stamp_ns,
        frame_published_ns: now_ns(),
        cameras,
    };
    for burst in 0..BURSTS {
        std::thread::sleep(Duration::from_millis(300));
        let now = now_ns();
        let past = now - 5_000_000_000;
        let future = now + 3_600_000_000_000;
        // Frames: a payload that does not match the header, no width, an
        // unknown encoding, rows narrower than the image, a stamp gone back.
        send_frame(good(now), 1000);
        send_frame(
            FrameHeader {
                width: 0,
                ..good(now)
            },
            2 * 640 * 480,
        );
        send_frame(
            FrameHeader {
                encoding: 99,
                ..good(now)
            },
            2 * 640 * 480,
        );
        send_frame(
            FrameHeader {
                stride: 100,
                ..good(now)
            },
            2 * 100 * 480,
        );
        send_frame(good(past), 2 * 640 * 480);
        // Joint states: non-finite, too many joints, an unknown phase, a stamp gone back.
        joints
            .send(JointState {
                q: [f64::NAN; 8],
                ..state(now)
            })
            .unwrap();
        joints
            .send(JointState {
                dof: 9,
                ..state(now)
            })
            .unwrap();
        joints
            .send(JointState {
                phase: 7,
                ..state(now)
            })
            .unwrap();
        joints.send(state(past)).unwrap();
        // Joint positions: non-finite, too many joints, a stamp gone back;
        // a pose goal for another arm.
        let reading = |stamp_ns| JointPositions {
            stamp_ns,
            dof: 4,
            ..Default::default()
        };
        positions
            .send(JointPositions {
                q: [f64::NAN; 8],
                ..reading(now)
            })
            .unwrap();
        positions
            .send(JointPositions {
                dof: 9,
                ..reading(now)
            })
            .unwrap();
        positions.send(reading(past)).unwrap();
        goals
            .send(PoseGoal {
                dof: 7,
                ..Default::default()
            })
            .unwrap();
        // Detections: a non-finite corner, too many markers, an id out of
        // range, a stamp gone back, a stamp an hour ahead.
        detections
            .send(detection(
                now,
                [marker(0, 1, f64::NAN), CameraMarkers::default()],
            ))
            .unwrap();
        let overfull = CameraMarkers {
            count: 99,
            ..Default::default()
        };
        detections
            .send(detection(now, [overfull, CameraMarkers::default()]))
            .unwrap();
        detections
            .send(detection(now, [marker(5000, 1, 10.0), marker(0, 1, 10.0)]))
            .unwrap();
        detections
            .send(detection(past, [marker(0, 1, 10.0), marker(0, 1, 10.0)]))
            .unwrap();
        detections
            .send(detection(future, [marker(0, 1, 10.0), marker(0, 1, 10.0)]))
            .unwrap();
        if burst == BURSTS - 1 {
            // Once: a frame and a joint state stamped an hour ahead, which
            // must not hold back the real ones after them for long.
            send_frame(good(future), 2 * 640 * 480);
            joints.send(state(future)).unwrap();
        }
    }
}

/// A rogue publisher on every input topic while the pipeline runs: each
/// stage drops each bad message with a counted warning, nothing panics or
/// restarts, and the calibration completes as usual.
#[test]
fn malformed_messages_are_dropped_counted_and_harmless() {
    let mut run = Launcher::start("rogue", true);
    let prefix = run.prefix.clone();
    run.wait_paired(1);
    rogue(&prefix);
    let log_path = run.out.join("mirror0/stages.log");
    let (placement, stderr) = run.finish();
    assert_eq!(placement["restarts"], 0, "{stderr:?}");
    assert_plane_near_truth(&placement);
    let k = BURSTS;
    // Five bad frames a burst, plus up to three real ones after the frame
    // from the future (the tracker then takes the real stream back).
    let tracker = stage_counter_summed_over_processes(&placement, "tracker_proc", "rejected");
    assert!(
        (5 * k..=5 * k + 3).contains(&tracker),
        "tracker rejected {tracker}"
    );
    // Three bad joint positions and one bad goal a burst.
    let camera =
        stage_counter_summed_over_processes(&placement, "camera_proc", "arm_messages_rejected");
    assert_eq!(camera, 4 * k, "camera rejected {camera}");
    let kinematics = stage_counter_summed_over_processes(
        &placement,
        "kinematics_proc",
        "joint_positions_rejected",
    );
    assert_eq!(kinematics, 3 * k, "kinematics_proc rejected {kinematics}");
    // Five bad detections and four bad joint states a burst, the joint
    // state and the frame's detections from the future.
    let mirror = placement["report"]["counters"]["rejected"]
        .as_u64()
        .unwrap();
    assert_eq!(mirror, 9 * k + 2, "mirror stage rejected {mirror}");
    let log = std::fs::read_to_string(log_path).unwrap();
    for what in [
        "dropping a frame",
        "dropping a joint state",
        "dropping a joint positions message",
        "dropping a pose goal",
        "dropping a detection",
    ] {
        assert!(log.contains(what), "no `{what}` warning in the stages' log");
    }
    assert!(!log.contains("panicked"), "a stage panicked");
    eprintln!(
        "rogue: tracker rejected {tracker}, camera {camera}, kinematics {kinematics}, mirror stage {mirror}; plane {} deg",
        placement["plane_angle_deg"]
    );
    // The recorder kept every message, the rogue ones too.
    let recording = placement["recording"].as_str().expect("a recording");
    let recording = recorder::reader::Recording::open(recording).unwrap();
    let damage = &recording.contents().damage;
    assert!(damage.is_none(), "{damage:?}");
}

/// Shared memory: every file the stages create is the owner's alone, and
/// what a SIGKILLed stage leaves is removed when the next one starts, which
/// then attaches to the same services.
#[test]
fn shared_memory_is_private_and_a_crash_leaves_nothing_behind() {
    let prefix = unique_prefix("shm");
    let dir = tempfile::tempdir().unwrap();
    let start = |log: &str| {
        KillOnDrop(
            Command::new(stage_binaries().join("tracker_proc"))
                .args(["run", "--prefix", &prefix])
                .stderr(std::fs::File::create(dir.path().join(log)).unwrap())
                .spawn()
                .unwrap(),
        )
    };
    // Holding the services, as the launcher does.
    let bus = Bus::new(&prefix, "shm_test").unwrap();
    let _services = bus.open_all().unwrap();
    let mut first = start("first.log");
    // Killed once it has all its ports: iceoryx2 0.10 cannot fully remove a
    // node killed while creating one (see `remove_dead_nodes`).
    wait_for_line(
        &dir.path().join("first.log"),
        "tracking",
        Duration::from_secs(30),
    );
    let wait_attached = || {
        let started = Instant::now();
        while bus.subscriber_count(TopicId::Frames).unwrap() < 1 {
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "tracker never attached"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    wait_attached();
    for root in ["/dev/shm", "/tmp/iceoryx2"] {
        for path in files_under(Path::new(root)) {
            let name = path.file_name().unwrap().to_string_lossy().to_string();
            // iceoryx2's one machine-wide management segment.
            if !name.starts_with("iox2_") || name.ends_with(".global_mgmt") {
                continue;
            }
            let Ok(meta) = std::fs::metadata(&path) else {
                continue;
            };
            let mode = std::os::unix::fs::PermissionsExt::mode(&meta.permissions());
            assert_eq!(
                mode & 0o077,
                0,
                "{} is open to others: {mode:o}",
                path.display()
            );
        }
    }
    let pid = first.0.id() as i32;
    first.0.kill().unwrap();
    first.0.wait().unwrap();
    let node_of = |pid: i32| {
        let mut found = None;
        Node::<ipc::Service>::list(Config::global_config(), |state| {
            let id = *state.node_id();
            if id.pid::<ipc::Service>().is_ok_and(|p| p.value() == pid) {
                found = Some(match state {
                    NodeState::Alive(_) => "alive",
                    NodeState::Dead(_) => "dead",
                    NodeState::Inaccessible(_) => "inaccessible",
                    NodeState::Undefined(_) => "undefined",
                });
            }
            CallbackProgression::Continue
        })
        .unwrap();
        found
    };
    // Listing the nodes takes each node's monitor lock for a moment, which
    // would race with the new tracker's cleanup: look before and after only.
    assert_eq!(node_of(pid), Some("dead"), "the killed tracker's node");
    // Started as the launcher restarts a stage: again if it fails to come
    // up (iceoryx2 can find a service of the dead process half removed).
    let mut attempts = 0;
    let (_second, log) = 'up: loop {
        attempts += 1;
        assert!(attempts <= 3, "the tracker did not come up in 3 attempts");
        let mut second = start(&format!("second{attempts}.log"));
        let log_path = dir.path().join(format!("second{attempts}.log"));
        let started = Instant::now();
        loop {
            let log = std::fs::read_to_string(&log_path).unwrap_or_default();
            if log.contains("tracking") {
                break 'up (second, log);
            }
            if second.0.try_wait().unwrap().is_some() {
                eprintln!("restarted tracker failed: {log}");
                break;
            }
            assert!(
                started.elapsed() < Duration::from_secs(20),
                "the restarted tracker hangs: {log}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    // The cleanup may still be finishing when the tracker logs.
    let started = Instant::now();
    while node_of(pid).is_some() && started.elapsed() < Duration::from_secs(2) {
        std::thread::sleep(Duration::from_millis(100));
    }
    assert_eq!(
        node_of(pid),
        None,
        "the dead tracker's node is still there: {log}"
    );
    // Its subscriber port is gone from the service too: only the new one counts.
    wait_attached();
    assert_eq!(bus.subscriber_count(TopicId::Frames).unwrap(), 1);
}

fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let path = entry.path();
        if path.is_dir() {
            out.extend(files_under(&path));
        } else {
            out.push(path);
        }
    }
    out
}
