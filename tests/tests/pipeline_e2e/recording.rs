//! The live run's recording: replayed into the stages it feeds, read by an
//! independent MCAP reader, and written by a recorder killed mid-run.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use recorder::channels::TopicId;
use recorder::reader::Recording;
use tests::python::python_with_mcap_reader;
use tests::{KillOnDrop, stage_binaries, unique_prefix, wait_exit};

use super::{live_run, wait_for_line};

/// Every lossless message of a recording, per topic, as bytes.
fn lossless(path: &Path) -> BTreeMap<TopicId, Vec<Vec<u8>>> {
    Recording::open(path).unwrap().lossless_by_topic().unwrap()
}

fn recording_a() -> PathBuf {
    live_run().out.join("mirror0/recording.mcap")
}

fn spawn(name: &str, args: &[&str], log: &Path) -> KillOnDrop {
    let log = std::fs::File::create(log).unwrap();
    KillOnDrop(
        Command::new(stage_binaries().join(name))
            .args(args)
            .stdout(Stdio::piped())
            .stderr(log)
            .spawn()
            .unwrap(),
    )
}

fn interrupt(child: &mut Child) {
    Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
}

/// Starts `replay` of the live recording on `prefix` and waits until its
/// services exist (the stages must come after).
fn start_replay(dir: &Path, prefix: &str, kind: &str, pace: &str, subscribers: &str) -> KillOnDrop {
    let log = dir.join("replay.log");
    let replay = spawn(
        "replay",
        &[
            recording_a().to_str().unwrap(),
            "--prefix",
            prefix,
            "--kind",
            kind,
            "--pace",
            pace,
            "--wait-subscribers",
            subscribers,
            "--json",
        ],
        &log,
    );
    wait_for_line(&log, "services created", Duration::from_secs(60));
    replay
}

/// Replays the live recording (`kind` frames or detections) in lockstep
/// into fresh stages and a recorder; returns the new recording.
fn replay_into(kind: &str, dir: &Path) -> PathBuf {
    let rig = live_run().out.join("mirror0/rig.toml");
    let prefix = unique_prefix(&format!("replay_{kind}"));
    let b = dir.join(format!("replay_{kind}.mcap"));
    let mut replay = start_replay(dir, &prefix, kind, "lockstep", "2");
    let mut recorder = spawn(
        "recorder",
        &[
            "--prefix",
            &prefix,
            "--out",
            b.to_str().unwrap(),
            "--no-drop",
            "--rig",
            rig.to_str().unwrap(),
        ],
        &dir.join("recorder.log"),
    );
    let mut tracker = (kind == "frames").then(|| {
        spawn(
            "tracker_proc",
            &["run", "--prefix", &prefix],
            &dir.join("tracker.log"),
        )
    });
    let mut mirror = spawn(
        "mirror_proc",
        &[
            "run",
            "--prefix",
            &prefix,
            "--rig",
            rig.to_str().unwrap(),
            "--method",
            "joint+kinematics",
            "--min-train",
            "8",
            "--report",
            dir.join("report.json").to_str().unwrap(),
        ],
        &dir.join("mirror.log"),
    );
    let started = Instant::now();
    let status = wait_exit(&mut replay.0, Duration::from_secs(120), "replay");
    let log = std::fs::read_to_string(dir.join("replay.log")).unwrap();
    assert!(status.success(), "replay failed: {log}");
    let mut stats = String::new();
    std::io::Read::read_to_string(replay.0.stdout.as_mut().unwrap(), &mut stats).unwrap();
    let stats: serde_json::Value = serde_json::from_str(&stats).unwrap();
    let recorded = stats["recorded_seconds"].as_f64().unwrap();
    eprintln!(
        "replay of {kind}: {} messages, {recorded:.1} s recorded in {:.1} s ({:.1}x real time)",
        stats["published"],
        stats["wall_seconds"].as_f64().unwrap(),
        stats["recorded_seconds"].as_f64().unwrap() / stats["wall_seconds"].as_f64().unwrap()
    );
    assert!(
        wait_exit(&mut mirror.0, Duration::from_secs(60), "mirror_proc").success(),
        "mirror_proc failed: {}",
        std::fs::read_to_string(dir.join("mirror.log")).unwrap()
    );
    // Stop in pipeline order: each stage takes what is waiting first.
    if let Some(t) = tracker.as_mut() {
        interrupt(&mut t.0);
        assert!(wait_exit(&mut t.0, Duration::from_secs(20), "tracker_proc").success());
    }
    interrupt(&mut recorder.0);
    assert!(
        wait_exit(&mut recorder.0, Duration::from_secs(60), "recorder").success(),
        "recorder failed: {}",
        std::fs::read_to_string(dir.join("recorder.log")).unwrap()
    );
    eprintln!(
        "replay of {kind} with stages: {:.1} s",
        started.elapsed().as_secs_f64()
    );
    b
}

/// The arm driver's topics: upstream of the joint states a replay
/// publishes, so a replay does not make them again.
const ARM_DRIVER: [TopicId; 2] = [TopicId::JointPositions, TopicId::PoseGoal];

fn assert_same(
    a: &BTreeMap<TopicId, Vec<Vec<u8>>>,
    b: &BTreeMap<TopicId, Vec<Vec<u8>>>,
    topic: TopicId,
) {
    let (x, y) = (&a[&topic], &b[&topic]);
    assert!(
        !x.is_empty(),
        "{} is empty in the live recording",
        topic.name()
    );
    assert_eq!(x.len(), y.len(), "{}: message counts differ", topic.name());
    for (k, (p, q)) in x.iter().zip(y).enumerate() {
        assert!(p == q, "{}: message {k} differs", topic.name());
    }
}

/// Every message of every channel (lossless and viewing): topic -> (log time, bytes).
fn all_channels(path: &Path) -> BTreeMap<String, Vec<(u64, Vec<u8>)>> {
    let mut out: BTreeMap<String, Vec<(u64, Vec<u8>)>> = BTreeMap::new();
    Recording::open(path)
        .unwrap()
        .for_each_raw(|topic, log_time, data| {
            out.entry(topic.to_string())
                .or_default()
                .push((log_time, data.to_vec()))
        })
        .unwrap();
    out
}

/// Channels equal message for message (log time and bytes), except `skip`.
fn assert_channels_equal(a: &Path, b: &Path, skip: &[&str]) {
    let (a, b) = (all_channels(a), all_channels(b));
    let mut compared = 0;
    for (topic, x) in &a {
        if skip.contains(&topic.as_str()) {
            continue;
        }
        let y = b.get(topic).map_or(&[][..], |v| &v[..]);
        assert_eq!(x.len(), y.len(), "{topic}: message counts differ");
        for (k, (p, q)) in x.iter().zip(y).enumerate() {
            assert!(p == q, "{topic}: message {k} differs");
        }
        compared += x.len();
    }
    assert!(compared > 1000, "only {compared} messages compared");
    eprintln!(
        "{compared} messages on {} channels identical",
        a.len() - skip.len()
    );
}

#[test]
fn record_a_equals_replay_of_its_frames_through_tracker_and_mirror_stage() {
    let dir = tempfile::tempdir().unwrap();
    let a_path = recording_a();
    let b_path = replay_into("frames", dir.path());
    let (a, b) = (lossless(&a_path), lossless(&b_path));
    for topic in TopicId::ALL.into_iter().filter(|t| !ARM_DRIVER.contains(t)) {
        assert_same(&a, &b, topic);
    }
    // The viewing channels too: images, overlays, transforms, scene.
    assert_channels_equal(&a_path, &b_path, &ARM_DRIVER.map(TopicId::name));
}

#[test]
fn record_a_equals_replay_of_its_detections_through_the_mirror_stage() {
    let dir = tempfile::tempdir().unwrap();
    let a_path = recording_a();
    let b_path = replay_into("detections", dir.path());
    let (a, b) = (lossless(&a_path), lossless(&b_path));
    assert!(!b.contains_key(&TopicId::Frames));
    for topic in TopicId::ALL
        .into_iter()
        .filter(|t| *t != TopicId::Frames && !ARM_DRIVER.contains(t))
    {
        assert_same(&a, &b, topic);
    }
    let images = [
        "frames",
        "/camera/left/image",
        "/camera/right/image",
        "joint_positions",
        "pose_goal",
    ];
    assert_channels_equal(&a_path, &b_path, &images);
    // Two replays: identical channels again (only publish times, chunk
    // boundaries and the interleaving of channels differ between files).
    let c_dir = tempfile::tempdir().unwrap();
    let c_path = replay_into("detections", c_dir.path());
    assert_channels_equal(&b_path, &c_path, &images);
}

/// `key=N` from the last line of `log` that contains `what`.
fn logged_count(log: &str, what: &str, key: &str) -> u64 {
    let line = log
        .lines()
        .rev()
        .find(|l| l.contains(what))
        .unwrap_or_else(|| panic!("no `{what}` in the stage log"));
    let at = line.find(&format!("{key}=")).unwrap() + key.len() + 1;
    line[at..]
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

/// Runs `tests/python/<script>` with `args`: success and its output.
fn run_python(script: &str, args: &[&str]) -> (bool, String) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("python")
        .join(script);
    let output = Command::new(python_with_mcap_reader())
        .arg(&script)
        .args(args)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&output.stdout).to_string()
        + &String::from_utf8_lossy(&output.stderr);
    (output.status.success(), text)
}

/// Runs `tests/node/<script>` with `args` on the npm packages that
/// `scripts/test.sh` installs into `target/node`: exit code and output.
fn run_node(script: &str, args: &[&str]) -> (Option<i32>, String) {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    let modules = here.join("../target/node/node_modules");
    assert!(
        modules.join("@foxglove/ws-protocol").exists(),
        "{} is missing: run scripts/test.sh once (it installs the npm `@foxglove/ws-protocol` \
         client there)",
        modules.display()
    );
    let output = Command::new("node")
        .arg(here.join("node").join(script))
        .args(args)
        .env("NODE_PATH", &modules)
        .output()
        .expect("node runs (scripts/setup.sh installs it)");
    let text = String::from_utf8_lossy(&output.stdout).to_string()
        + &String::from_utf8_lossy(&output.stderr);
    (output.status.code(), text)
}

#[test]
fn an_independent_reader_sees_every_published_message_and_the_foxglove_schemas_decode() {
    let out = &live_run().out;
    let log = std::fs::read_to_string(out.join("mirror0/stages.log")).unwrap();
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("mirror0/report.json")).unwrap())
            .unwrap();
    let expected = serde_json::json!({
        "frames": logged_count(&log, "camera done", "frames"),
        "detections": logged_count(&log, "tracker stopped", "frames"),
        "joint_state": logged_count(&log, "pose plan done states", "states"),
        "samples": report["counters"]["paired"],
        "calibration": log.lines().filter(|l| l.contains(" calibration") && l.contains("revision=")).count(),
        "predictions": report["test_samples"],
    });
    let (ok, text) = run_python(
        "check_recording.py",
        &[recording_a().to_str().unwrap(), &expected.to_string()],
    );
    assert!(ok, "{text}");
    eprintln!("{text}");
}

#[test]
fn a_recorder_killed_mid_run_leaves_every_message_up_to_its_last_flush() {
    let dir = tempfile::tempdir().unwrap();
    let a_path = recording_a();
    let a = lossless(&a_path);
    let prefix = unique_prefix("killed");
    let killed = dir.path().join("killed.mcap");
    let mut replay = start_replay(dir.path(), &prefix, "all", "original", "1");
    let mut recorder = spawn(
        "recorder",
        &["--prefix", &prefix, "--out", killed.to_str().unwrap()],
        &dir.path().join("recorder.log"),
    );
    // Kill it once a good part of the run is on disk (by size, not by the
    // clock, so a loaded machine does not change what is tested).
    let a_size = std::fs::metadata(&a_path).unwrap().len();
    let started = Instant::now();
    while std::fs::metadata(&killed).map_or(0, |m| m.len()) < a_size / 3 {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "the recording does not grow"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    recorder.0.kill().unwrap(); // SIGKILL
    recorder.0.wait().unwrap();
    interrupt(&mut replay.0);
    wait_exit(&mut replay.0, Duration::from_secs(20), "replay");

    let recording = Recording::open(&killed).unwrap();
    let contents = recording.contents();
    assert!(
        contents.damage.is_some(),
        "a killed recorder writes no footer"
    );
    let (first, last) = contents.time_range.unwrap();
    let covered = (last - first) as f64 / 1e9;
    // A third of the file was on disk, flushed chunk by chunk.
    assert!(covered > 1.0, "only {covered:.2} s readable after the kill");
    let b = lossless(&killed);
    for topic in TopicId::ALL {
        let got = b.get(&topic).map_or(&[][..], |v| &v[..]);
        let all = &a[&topic];
        // Nothing lost before the last flush: each topic is a prefix of what was published.
        assert!(got.len() <= all.len());
        assert!(
            got == &all[..got.len()],
            "{}: not a prefix of the published messages",
            topic.name()
        );
    }
    eprintln!(
        "killed mid-run: {covered:.2} s of messages readable, {} frames, {} joint states",
        b.get(&TopicId::Frames).map_or(0, Vec::len),
        b.get(&TopicId::JointState).map_or(0, Vec::len)
    );
}

#[test]
fn replay_reads_a_truncated_file_partially_and_refuses_a_foreign_one() {
    let dir = tempfile::tempdir().unwrap();
    let whole = std::fs::read(recording_a()).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &whole[..whole.len() * 3 / 5]).unwrap();
    let run = |file: &Path| {
        Command::new(stage_binaries().join("replay"))
            .args([
                file.to_str().unwrap(),
                "--prefix",
                &unique_prefix("cut"),
                "--kind",
                "all",
            ])
            .args(["--wait-subscribers", "0", "--json"])
            .output()
            .unwrap()
    };
    let output = run(&cut);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("damaged"), "no warning: {stderr}");
    let stats: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let published = stats["published"].as_u64().unwrap();
    let total: usize = lossless(&recording_a()).values().map(Vec::len).sum();
    assert!(
        published > 0 && (published as usize) < total,
        "{published} of {total}"
    );

    let foreign = dir.path().join("rig.toml");
    std::fs::copy(live_run().out.join("mirror0/rig.toml"), &foreign).unwrap();
    let output = run(&foreign);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    let last = stderr.lines().last().unwrap();
    assert!(
        last.starts_with("replay: error: ")
            && last.contains("rig.toml")
            && last.contains("not an MCAP file"),
        "{stderr}"
    );
}

/// Starts a recorder of `prefix` with the rig and a live view on a free
/// port (and `extra` options); returns it and the port, once it serves.
fn start_live_view(dir: &Path, prefix: &str, extra: &[&str]) -> (KillOnDrop, String) {
    let log = dir.join("recorder.log");
    let out = dir.join("live.mcap");
    let rig = live_run().out.join("mirror0/rig.toml");
    let mut args = vec![
        "--prefix",
        prefix,
        "--out",
        out.to_str().unwrap(),
        "--rig",
        rig.to_str().unwrap(),
        "--live-view",
        "0",
    ];
    args.extend(extra);
    let recorder = spawn("recorder", &args, &log);
    wait_for_line(&log, "ws://127.0.0.1:", Duration::from_secs(60));
    let text = std::fs::read_to_string(&log).unwrap();
    let at = text.find("ws://127.0.0.1:").unwrap() + "ws://127.0.0.1:".len();
    let port = text[at..]
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    (recorder, port)
}

#[test]
fn the_live_view_serves_foxglove_clients_while_recording() {
    let dir = tempfile::tempdir().unwrap();
    let prefix = unique_prefix("live_view");
    let mut replay = start_replay(dir.path(), &prefix, "all", "original", "1");
    let (mut recorder, port) = start_live_view(dir.path(), &prefix, &[]);
    let (ok, text) = run_python("live_view_client.py", &[&port]);
    // The official npm client library: it works offering the SDK's
    // subprotocol, and the older protocol name is refused by the SDK's
    // handshake (the README says which viewers connect).
    let (sdk_code, sdk_text) = run_node("live_view_client.js", &[&port, "foxglove.sdk.v1"]);
    let (old_code, old_text) = run_node("live_view_client.js", &[&port, "foxglove.websocket.v1"]);
    interrupt(&mut replay.0);
    wait_exit(&mut replay.0, Duration::from_secs(20), "replay");
    interrupt(&mut recorder.0);
    assert!(wait_exit(&mut recorder.0, Duration::from_secs(30), "recorder").success());
    assert!(ok, "{text}");
    eprintln!("{text}");
    assert_eq!(sdk_code, Some(0), "{sdk_text}");
    assert!(sdk_text.contains("\"/mirror/tf\""), "{sdk_text}");
    eprintln!("npm client: {sdk_text}");
    assert_eq!(old_code, Some(3), "{old_text}");
    assert!(old_text.contains("\"refused\":400"), "{old_text}");
}

/// A viewer that connects once everything has been published (the replay
/// has ended, nothing flows) still gets the mirror, the mirror cameras and
/// the camera calibrations at once.
#[test]
fn a_viewer_joining_after_the_calibration_gets_the_current_state_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let prefix = unique_prefix("late_joiner");
    let mut replay = start_replay(dir.path(), &prefix, "all", "lockstep", "1");
    let (mut recorder, port) = start_live_view(dir.path(), &prefix, &["--no-view-images"]);
    assert!(wait_exit(&mut replay.0, Duration::from_secs(120), "replay").success());
    let (ok, text) = run_python("live_view_late_joiner.py", &[&port]);
    interrupt(&mut recorder.0);
    assert!(wait_exit(&mut recorder.0, Duration::from_secs(30), "recorder").success());
    assert!(ok, "{text}");
    eprintln!("{text}");
}

#[test]
fn a_full_disk_stops_the_recorder_with_one_line_and_a_readable_file_while_stages_go_on() {
    let dir = tempfile::tempdir().unwrap();
    let a_path = recording_a();
    let a = lossless(&a_path);
    let a_size = std::fs::metadata(&a_path).unwrap().len();
    let prefix = unique_prefix("full_disk");
    let mut replay = start_replay(dir.path(), &prefix, "frames", "4x", "2");
    // The file may grow to about a third of the live recording: the shell's
    // file-size limit stands in for a full disk (SIGXFSZ ignored, so writes
    // fail with EFBIG like they would with ENOSPC).
    let out = dir.path().join("full.mcap");
    let limit_blocks = (a_size / 3 / 1024).to_string();
    let recorder_log = dir.path().join("recorder.log");
    let mut recorder = KillOnDrop(
        Command::new("sh")
            .args([
                "-c",
                "ulimit -f \"$0\"; trap '' XFSZ; exec \"$@\"",
                &limit_blocks,
                stage_binaries().join("recorder").to_str().unwrap(),
                "--prefix",
                &prefix,
                "--out",
                out.to_str().unwrap(),
            ])
            .stderr(std::fs::File::create(&recorder_log).unwrap())
            .spawn()
            .unwrap(),
    );
    let rig = live_run().out.join("mirror0/rig.toml");
    let mut tracker = spawn(
        "tracker_proc",
        &["run", "--prefix", &prefix],
        &dir.path().join("tracker.log"),
    );
    let mut mirror = spawn(
        "mirror_proc",
        &[
            "run",
            "--prefix",
            &prefix,
            "--rig",
            rig.to_str().unwrap(),
            "--report",
            dir.path().join("report.json").to_str().unwrap(),
        ],
        &dir.path().join("mirror.log"),
    );
    let status = wait_exit(&mut recorder.0, Duration::from_secs(120), "recorder");
    let log = std::fs::read_to_string(&recorder_log).unwrap();
    assert_eq!(status.code(), Some(1), "{log}");
    let last = log.lines().last().unwrap();
    assert!(
        last.starts_with("recorder: error: recording stopped: ") && last.contains("full.mcap"),
        "{log}"
    );
    // The rest of the pipeline goes on and finishes its calibration.
    assert!(wait_exit(&mut replay.0, Duration::from_secs(120), "replay").success());
    assert!(
        wait_exit(&mut mirror.0, Duration::from_secs(60), "mirror_proc").success(),
        "{}",
        std::fs::read_to_string(dir.path().join("mirror.log")).unwrap()
    );
    interrupt(&mut tracker.0);
    wait_exit(&mut tracker.0, Duration::from_secs(20), "tracker_proc");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
            .unwrap();
    assert!(report["calibration"].is_object(), "{report}");
    // What was written before the disk filled is there, intact, in order.
    let b = lossless(&out);
    let frames = b.get(&TopicId::Frames).map_or(0, Vec::len);
    assert!(frames > 0, "nothing readable: {log}");
    for (topic, got) in &b {
        assert!(
            got == &a[topic][..got.len()],
            "{}: not a prefix",
            topic.name()
        );
    }
    eprintln!(
        "disk full after {frames} of {} frames: {last}",
        a[&TopicId::Frames].len()
    );
}

/// `replay diff A B` with its exit code and output.
fn diff(a: &Path, b: &Path, extra: &[&str]) -> (Option<i32>, String, String) {
    let output = Command::new(stage_binaries().join("replay"))
        .arg("diff")
        .args([a, b])
        .args(extra)
        .output()
        .unwrap();
    (
        output.status.code(),
        String::from_utf8_lossy(&output.stdout).to_string(),
        String::from_utf8_lossy(&output.stderr).to_string(),
    )
}

/// The channels downstream of the detections.
const DOWNSTREAM: &str = "samples,calibration,predictions,located";

/// `pipeline --replay` re-runs the mirror stage on the recorded detections
/// with the rig, plan and config the recording holds: the downstream
/// channels come out identical (`replay diff` exits 0). With another
/// method the calibration differs, and `diff` exits 1 naming the plane.
#[test]
fn a_recorded_run_re_run_by_the_launcher_diffs_identical_and_another_method_does_not() {
    let dir = tempfile::tempdir().unwrap();
    let rerun = |method: Option<&str>, out: &Path| {
        let mut command = Command::new(stage_binaries().join("pipeline"));
        command
            .args([
                "--replay",
                recording_a().to_str().unwrap(),
                "--kind",
                "detections",
            ])
            .args([
                "--out",
                out.to_str().unwrap(),
                "--prefix",
                &unique_prefix("rerun"),
            ])
            .args(["--report", "json"]);
        if let Some(m) = method {
            command.args(["--method", m]);
        }
        let output = command.output().unwrap();
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
        assert!(out.join("recording.mcap").exists() && out.join("report.json").exists());
        report
    };
    let same = dir.path().join("same");
    let report = rerun(None, &same);
    let live: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(live_run().out.join("mirror0/report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        report["placements"][0]["report"]["calibration"], live["calibration"],
        "the re-run's calibration is the live one"
    );
    let b = same.join("recording.mcap");
    let (code, out, err) = diff(&recording_a(), &b, &["--channels", DOWNSTREAM]);
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(out.contains("identical: 4 channels"), "{out}");
    let (code, json, _) = diff(&recording_a(), &b, &["--channels", DOWNSTREAM, "--json"]);
    assert_eq!(code, Some(0));
    let json: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(json["identical"], true);
    assert!(
        json["channels"]
            .as_array()
            .unwrap()
            .iter()
            .all(|c| c["count_a"] == c["count_b"])
    );

    let other = dir.path().join("joint");
    rerun(Some("joint"), &other);
    let (code, out, err) = diff(
        &recording_a(),
        &other.join("recording.mcap"),
        &["--channels", DOWNSTREAM],
    );
    assert_eq!(code, Some(1), "{out}{err}");
    let calibration = out.lines().find(|l| l.starts_with("calibration")).unwrap();
    assert!(calibration.contains("differs in: method, plane"), "{out}");
    assert!(out.contains("plane_angle_deg: max "), "{out}");
    assert!(
        out.lines()
            .any(|l| l.starts_with("samples") && l.ends_with("identical")),
        "{out}"
    );
    eprintln!("{out}");
}

/// `replay diff` on a damaged file, a foreign file or an unknown channel:
/// one line on stderr, exit 2.
#[test]
fn diff_of_damaged_or_foreign_files_is_a_one_line_error_and_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let whole = std::fs::read(recording_a()).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &whole[..whole.len() / 2]).unwrap();
    let foreign = live_run().out.join("mirror0/rig.toml");
    let missing = dir.path().join("missing.mcap");
    for (b, extra, expect) in [
        (&cut, &[][..], "damaged after"),
        (&foreign, &[][..], "not an MCAP file"),
        (&missing, &[][..], "cannot read"),
        (
            &recording_a(),
            &["--channels", "nope"][..],
            "--channels: no channel `nope`",
        ),
    ] {
        let (code, out, err) = diff(&recording_a(), b, extra);
        assert_eq!(code, Some(2), "{out}{err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(
            err.starts_with("replay: error: ") && err.contains(expect),
            "{err}"
        );
        assert!(out.is_empty(), "{out}");
    }
}
