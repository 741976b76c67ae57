//! The ROS 2 stage against an independent implementation of the wire:
//! PyPI `rosbags` (CDR codec, Jazzy definitions, RIHS01 hashes) and PyPI
//! `eclipse-zenoh`. Nothing here checks our encoder against itself.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use ros2_proc::msgs::*;
use ros2_proc::types::RosType;
use ros2_proc::wire;
use tests::python::python_with_ros2_wire;
use tests::{KillOnDrop, free_port, stage_binaries, unique_prefix};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn python(script: &str) -> Command {
    let mut c = Command::new(python_with_ros2_wire());
    c.arg(repo().join(script));
    c
}

fn header(sec: i32, nanosec: u32, frame: &str) -> Header {
    Header {
        stamp: Time { sec, nanosec },
        frame_id: frame.into(),
    }
}

/// The values `tests/ros2/rosbags_vectors.py` encodes.
fn our_vectors() -> Vec<(&'static str, Vec<u8>)> {
    fn entry<M: RosType>(m: M) -> (&'static str, Vec<u8>) {
        (M::NAME, wire::encode(&m).unwrap())
    }
    vec![
        entry(JointState {
            header: header(1, 2, "base"),
            name: vec!["j1".into(), "j2".into()],
            position: vec![0.5, -1.0],
            velocity: vec![],
            effort: vec![3.0],
        }),
        entry(JointTrajectory {
            header: header(0, 0, ""),
            joint_names: vec!["shoulder".into(), "elbow".into(), "wrist".into()],
            points: vec![JointTrajectoryPoint {
                positions: vec![0.1, 0.2, 0.3],
                time_from_start: Duration {
                    sec: 0,
                    nanosec: 300_000_000,
                },
                ..Default::default()
            }],
        }),
        entry(Image {
            header: header(1_700_000_000, 5, "left"),
            height: 2,
            width: 3,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: 3,
            data: vec![0, 1, 2, 250, 251, 255],
        }),
        entry(CameraInfo {
            header: header(7, 8, "left"),
            height: 480,
            width: 640,
            distortion_model: "plumb_bob".into(),
            d: vec![0.1, -0.2, 0.0, 0.0, 0.05],
            k: [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                500.0, 0.0, 320.0, 0.0, 0.0, 500.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
            binning_x: 0,
            binning_y: 0,
            roi: RegionOfInterest {
                x_offset: 1,
                y_offset: 2,
                height: 3,
                width: 4,
                do_rectify: true,
            },
        }),
        entry(TfMessage {
            transforms: vec![TransformStamped {
                header: header(3, 4, "world"),
                child_frame_id: "mirror".into(),
                transform: Transform {
                    translation: Vector3 {
                        x: 0.1,
                        y: 0.2,
                        z: 0.3,
                    },
                    rotation: Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: 0.6,
                        w: 0.8,
                    },
                },
            }],
        }),
        entry(PointStamped {
            header: header(9, 10, "world"),
            point: Point {
                x: -0.5,
                y: 0.25,
                z: 1.0,
            },
        }),
    ]
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

#[test]
fn cdr_payloads_are_rosbags_byte_for_byte() {
    let out = python("tests/ros2/rosbags_vectors.py").output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let theirs: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ours = our_vectors();
    assert_eq!(ours.len(), theirs.as_object().unwrap().len());
    for (name, bytes) in &ours {
        let expected = theirs[name].as_str().unwrap();
        assert_eq!(hex(bytes), expected, "{name}: ours vs rosbags");
    }
    // And rosbags' bytes decode to our values.
    let decoded = |name: &str| unhex(theirs[name].as_str().unwrap());
    let state: JointState = wire::decode(&decoded(JointState::NAME)).unwrap();
    assert_eq!(state.position, [0.5, -1.0]);
    assert_eq!(state.effort, [3.0]);
    let info: CameraInfo = wire::decode(&decoded(CameraInfo::NAME)).unwrap();
    assert_eq!(
        (info.k[2], info.p[6], info.roi.do_rectify),
        (320.0, 240.0, true)
    );
    let tf: TfMessage = wire::decode(&decoded(TfMessage::NAME)).unwrap();
    assert_eq!(tf.transforms[0].child_frame_id, "mirror");
    assert_eq!(tf.transforms[0].transform.rotation.w, 0.8);
    let image: Image = wire::decode(&decoded(Image::NAME)).unwrap();
    assert_eq!(image.data, [0, 1, 2, 250, 251, 255]);
    // The camera stage's in-place reading of the same bytes.
    let payload = decoded(Image::NAME);
    let view = ros2_proc::image::ImageView::parse(&payload).unwrap();
    assert_eq!(
        (view.header.stamp.sec, view.width, view.height, view.step),
        (1_700_000_000, 3, 2, 3)
    );
    assert_eq!(
        (view.encoding.as_str(), view.data.to_vec()),
        ("mono8", vec![0u8, 1, 2, 250, 251, 255])
    );
}

#[test]
fn the_type_table_is_what_rosbags_computes() {
    let out = python("scripts/ros2_types.py").output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let generated = String::from_utf8(out.stdout).unwrap();
    assert!(
        generated == ros2_proc::types::TABLE_JSON,
        "ros2_proc/ros2_types.json is stale: run `target/pyenv/bin/python scripts/ros2_types.py > ros2_proc/ros2_types.json`"
    );
}

/// A ROS 2 arm (Python: eclipse-zenoh and rosbags, behaving like
/// `joint_trajectory_controller`, with an extra joint, shuffled order, and
/// samples without attachment dropped) plays the arm of a whole run through
/// `pipeline --ros2`: the calibration completes with the plane within 0.5
/// deg and 5 mm of the truth, and the graph shows our node and endpoints in
/// rmw_zenoh's token format.
#[test]
fn a_ros2_arm_plays_the_arm_of_a_whole_run() {
    let dir = tempfile::tempdir().unwrap();
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut arm = KillOnDrop(
        python("tests/ros2/ros2_arm.py")
            .args([
                "--listen",
                &endpoint,
                "--joints",
                "joint1,joint2,joint3,joint4",
            ])
            .args(["--home", "0.6,0.0,0.0,0.0"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut lines = BufReader::new(arm.0.stdout.take().unwrap()).lines();
    let ready = lines.next().unwrap().unwrap();
    assert!(ready.contains("ready"), "{ready}");

    let config = dir.path().join("pipeline.toml");
    std::fs::write(
        &config,
        "preset = \"nico\"\nmirrors = [0]\ntrain_poses = 10\ntest_poses = 4\ndirect_poses = 2\n\
         method = \"joint+kinematics\"\nsource = \"sim\"\nfps = 30.0\nmove_ms = 300\ndwell_ms = 250\n\
         seed = 5\nmin_train = 8\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let output = Command::new(stage_binaries().join("pipeline"))
        .args(["--config", config.to_str().unwrap()])
        .args(["--out", out.to_str().unwrap()])
        .args(["--prefix", &unique_prefix("ros2_arm")])
        .args(["--report", "json", "--ros2", &endpoint])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    let log = std::fs::read_to_string(out.join("mirror0/stages.log")).unwrap_or_default();
    assert!(output.status.success(), "{stderr}\n{log}");

    // The arm's own account: every trajectory carried a good attachment,
    // sequence numbers from 1 without a gap.
    drop(arm.0.stdin.take());
    let summary: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    arm.0.wait().unwrap();
    let goals = summary["trajectories"].as_u64().unwrap();
    assert!(goals >= 16, "{summary}");
    assert_eq!(summary["without_attachment"], 0, "{summary}");
    assert_eq!(summary["bad_attachment"], 0, "{summary}");
    assert_eq!(summary["sequences_ok"], true, "{summary}");

    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let placement = &report["placements"][0];
    tests::report::assert_plane_near_truth(placement);

    // The graph, as rmw_zenoh's own discovery reads it.
    let tokens: Vec<&str> = summary["tokens"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_str().unwrap())
        .collect();
    let ours = |kind: &str, tail: &str| {
        tokens.iter().any(|t| {
            let parts: Vec<&str> = t.split('/').collect();
            parts.len() >= 9
                && parts[0] == "@ros2_lv"
                && parts[1] == "0"
                && parts[5] == kind
                && parts[6] == "%"
                && parts[8] == "mirror_arm"
                && t.ends_with(tail)
        })
    };
    assert!(ours("NN", "/mirror_arm"), "{tokens:?}");
    let trajectory = JointTrajectory::info();
    assert!(
        ours(
            "MP",
            &format!(
                "/%joint_trajectory_controller%joint_trajectory/{}/{}/::,10:,:,:,,",
                trajectory.dds_name, trajectory.hash
            )
        ),
        "{tokens:?}"
    );
    let state = JointState::info();
    assert!(
        ours(
            "MS",
            &format!(
                "/%joint_states/{}/{}/::,10:,:,:,,",
                state.dds_name, state.hash
            )
        ),
        "{tokens:?}"
    );
    // /tf_static, decoded by rosbags: the final revision's mirror frames are
    // the final calibration's; a node started after the first calibration
    // got the latched transforms too.
    let calibration: formats::calibration::CalibrationFile =
        serde_json::from_value(placement["report"]["calibration"].clone()).unwrap();
    let rig = formats::rig::read(out.join("mirror0/rig.toml")).unwrap();
    let last_tf = summary["last_tf"].as_array().expect("a /tf_static message");
    let frame = |child: &str| {
        let t = last_tf
            .iter()
            .find(|t| t["child"] == child)
            .unwrap_or_else(|| panic!("no {child} in {last_tf:?}"));
        assert_eq!(t["parent"], "world");
        let v = |k: &str| -> Vec<f64> {
            t[k].as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect()
        };
        (v("t"), v("q"))
    };
    let mirror_cameras = calibration.mirror_cameras(&rig);
    for (k, child) in ["mirror_camera_left", "mirror_camera_right"]
        .iter()
        .enumerate()
    {
        let expected = mirror_cameras[k].world_from_camera();
        let (t, q) = frame(child);
        let moved =
            (nalgebra::Vector3::new(t[0], t[1], t[2]) * 1e3 - expected.translation.vector).norm();
        let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q[3], q[0], q[1], q[2],
        ));
        let turned = q.angle_to(&expected.rotation).to_degrees();
        assert!(
            moved < 1e-6 && turned < 1e-6,
            "{child}: {moved} mm, {turned} deg off the calibration"
        );
    }
    let plane = calibration.plane().expect("a plane");
    let (t, _) = frame("mirror");
    let foot = plane.world_from_plane().translation.vector;
    assert!((nalgebra::Vector3::new(t[0], t[1], t[2]) * 1e3 - foot).norm() < 1e-6);
    let late = summary["late_joiner_tf"]
        .as_array()
        .unwrap_or_else(|| panic!("a late subscriber got no /tf_static: {summary}"));
    assert_eq!(late.len(), last_tf.len(), "{late:?}");

    // The run's recording as a ROS 2 bag, read back by rosbags.
    bag_equals_recording(&out.join("mirror0/recording.mcap"), &dir.path().join("bag"));

    let settle = &tests::report::stage_stats(placement, "kinematics_proc").unwrap()["latencies"]["goal_to_settled"]
        ["p50_ms"];
    eprintln!(
        "ros2 arm: plane {} deg / {} mm; {goals} trajectories; goal to settled p50 {settle} ms",
        placement["plane_angle_deg"], placement["plane_distance_mm"]
    );
    let _ = std::io::stderr().flush();
}

/// Runs `ros2_proc arm` against `tests/ros2/bad_publisher.py --case CASE`;
/// returns whether it succeeded and its stderr.
fn arm_against_bad_publisher(case: &str) -> (bool, String) {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    arm_against_publisher(case, &endpoint, &[], &[])
}

/// `ros2_proc arm` (with `arm_args`) against `bad_publisher.py --case
/// case` listening at `endpoint` (with `publisher_args`): whether the stage
/// succeeded, and its log.
fn arm_against_publisher(
    case: &str,
    endpoint: &str,
    publisher_args: &[&str],
    arm_args: &[&str],
) -> (bool, String) {
    // Built (or checked) before the publisher starts: it publishes for
    // 1.5 s only, and a first `cargo build` can take longer.
    let ros2_proc = stage_binaries().join("ros2_proc");
    let dir = tempfile::tempdir().unwrap();
    let rig = dir.path().join("rig.toml");
    formats::rig::write(&rig, &geometry::sim::nico_scene().rig).unwrap();
    let mut publisher = KillOnDrop(
        python("tests/ros2/bad_publisher.py")
            .args(["--listen", endpoint, "--case", case])
            .args(publisher_args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut lines = BufReader::new(publisher.0.stdout.take().unwrap()).lines();
    assert!(lines.next().unwrap().unwrap().contains("ready"));
    let output = Command::new(ros2_proc)
        .args(["arm", "--prefix", &unique_prefix(case)])
        .args(["--rig", rig.to_str().unwrap(), "--endpoint", endpoint])
        .args(["--silent-ms", "1000"])
        .args(arm_args)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    drop(publisher.0.stdin.take());
    (
        output.status.success(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

/// A router on mutual TLS (a PyPI zenoh peer configured as one) is reached
/// with the CA and a client certificate, and its joint states arrive; without
/// the client certificate the stage cannot open a session and says where.
#[test]
fn the_arm_stage_reaches_a_router_on_mutual_tls() {
    let certs = tempfile::tempdir().unwrap();
    let sides = ["router", "client"].map(|name| secure_link::certs::SideRequest {
        name: name.into(),
        hosts: vec!["127.0.0.1".into()],
    });
    secure_link::certs::write(certs.path(), &sides, 1, false).unwrap();
    let file = |name: &str| certs.path().join(name).to_str().unwrap().to_string();
    let tls_dir = ["--tls-dir", certs.path().to_str().unwrap()];
    let endpoint = format!("tls/127.0.0.1:{}", free_port());
    let (ca, cert, key) = (file("ca.pem"), file("client.pem"), file("client.key"));
    let (ok, stderr) = arm_against_publisher(
        "mixed",
        &endpoint,
        &tls_dir,
        &["--tls-ca", &ca, "--tls-cert", &cert, "--tls-key", &key],
    );
    // Stopped by the silence after the publisher's samples, which arrived.
    assert!(!ok, "{stderr}");
    assert!(
        stderr.contains("a joint state without joint \"joint4\""),
        "nothing crossed the TLS link: {stderr}"
    );
    let endpoint = format!("tls/127.0.0.1:{}", free_port());
    let (ok, stderr) = arm_against_publisher("mixed", &endpoint, &tls_dir, &["--tls-ca", &ca]);
    assert!(!ok, "{stderr}");
    let last = stderr.lines().last().unwrap_or_default();
    assert!(
        last.contains("cannot reach the ROS 2 graph at tls/127.0.0.1:"),
        "{stderr}"
    );
    assert!(!stderr.contains("joint4"), "{stderr}");
}

#[test]
fn a_humble_graph_gets_one_line_saying_so() {
    let (ok, stderr) = arm_against_bad_publisher("humble");
    assert!(!ok, "{stderr}");
    let last = stderr.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("ros2_proc: error: /joint_states comes from a ROS 2 Humble graph")
            && last.contains("Jazzy or later"),
        "{stderr}"
    );
}

#[test]
fn bad_joint_states_are_named_and_counted_and_silence_stops_the_stage() {
    let (ok, stderr) = arm_against_bad_publisher("mixed");
    assert!(!ok, "{stderr}");
    assert!(
        stderr.contains("a joint state without joint \"joint4\""),
        "{stderr}"
    );
    let other = format!("RIHS01_{}", "ab".repeat(32));
    assert!(
        stderr.contains(&other) && stderr.contains(JointState::info().hash),
        "both hashes named: {stderr}"
    );
    assert!(stderr.contains("no attachment"), "{stderr}");
    assert!(stderr.contains("malformed CDR"), "{stderr}");
    // Each kind of bad sample is named once or a bounded number of times,
    // not once per sample.
    assert!(stderr.lines().count() < 40, "{stderr}");
    let last = stderr.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("ros2_proc: error: no /joint_states from tcp/127.0.0.1:")
            && last.contains("for 1"),
        "{stderr}"
    );
}

/// A rendered stereo pair: both images, and the markers drawn in each.
type RenderedPair = ([Vec<u8>; 2], [Vec<renderer::render::DrawnMarker>; 2]);

/// Renders `pairs` stereo pairs of the simulated scene (mirror 0, the arm
/// at calibration poses) into `dir` as the image publisher reads them;
/// returns each pair's images and the markers drawn in them.
fn render_pairs(dir: &Path, pairs: usize) -> Vec<RenderedPair> {
    use geometry::sim::{Counts, Facing, SimWorld, generate, nico_noise, nico_scene};
    let counts = Counts {
        train: pairs,
        test: 0,
        direct: 0,
    };
    let data = generate(&nico_scene(), 0, &nico_noise(), counts, 3).unwrap();
    let world = SimWorld::nico(0).unwrap();
    let intr = world.rig.cameras[0].intrinsics;
    let mut renderer = renderer::Renderer::with_look(
        world,
        renderer::look::Look::named(renderer::look::LookName::Realistic),
    )
    .unwrap();
    let n = (intr.width * intr.height) as usize;
    let rendered: Vec<_> = data
        .train
        .iter()
        .enumerate()
        .map(|(k, sample)| {
            let (mut l, mut r) = (vec![0u8; n], vec![0u8; n]);
            let q = sample.joints.as_ref().unwrap();
            let truth = renderer
                .render(q, Facing::Mirror, k as u64, &mut l, &mut r)
                .unwrap();
            std::fs::write(dir.join(format!("{k:03}_left.gray")), &l).unwrap();
            std::fs::write(dir.join(format!("{k:03}_right.gray")), &r).unwrap();
            ([l, r], truth.markers)
        })
        .collect();
    std::fs::write(
        dir.join("manifest.json"),
        format!(
            "{{\"width\": {}, \"height\": {}, \"pairs\": {pairs}}}",
            intr.width, intr.height
        ),
    )
    .unwrap();
    rendered
}

/// A ROS 2 stereo camera (Python: eclipse-zenoh and rosbags) publishes
/// rendered pairs as `sensor_msgs/Image` in mono8, rgb8 and bgr8, with
/// padded rows, either image first; `ros2_proc camera` pairs them into
/// frames and `tracker_proc` finds in each frame the markers the simulator
/// drew, exactly as our detector finds them in the rendered images. What
/// cannot become a frame (a lone image, yuv422, another size, no
/// attachment) is counted, each kind named once.
#[test]
fn a_ros2_camera_feeds_the_tracker() {
    use messages::topics;
    use runtime::Bus;
    use std::time::{Duration, Instant};

    let dir = tempfile::tempdir().unwrap();
    let pairs = 6;
    let rendered = render_pairs(dir.path(), pairs);
    let (w, h) = {
        let k = geometry::sim::SimWorld::nico(0).unwrap().rig.cameras[0].intrinsics;
        (k.width as i32, k.height as i32)
    };
    let mut detector = tracker_proc::Detector::new(true).unwrap();

    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut camera_py = KillOnDrop(
        python("tests/ros2/image_publisher.py")
            .args(["--listen", &endpoint, "--dir", dir.path().to_str().unwrap()])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut lines = BufReader::new(camera_py.0.stdout.take().unwrap()).lines();
    assert!(lines.next().unwrap().unwrap().contains("ready"));

    let prefix = unique_prefix("ros2_camera");
    let bus = Bus::new(&prefix, "ros2_camera_test").unwrap();
    // Held for the test, as the launcher holds them for a run: the frames
    // service exists before the camera's first pair.
    let _services = bus.open_all().unwrap();
    let detections = bus.subscriber::<topics::Detections>().unwrap();
    let stats = dir.path().join("stats");
    std::fs::create_dir_all(&stats).unwrap();
    let bins = stage_binaries();
    let mut stage = KillOnDrop(
        Command::new(bins.join("ros2_proc"))
            .args(["camera", "--prefix", &prefix, "--endpoint", &endpoint])
            .env("MIRROR_STATS_DIR", &stats)
            .env("RUST_LOG", "warn")
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let _tracker = KillOnDrop(
        Command::new(bins.join("tracker_proc"))
            .args(["run", "--prefix", &prefix, "--full-scan-every", "1"])
            .spawn()
            .unwrap(),
    );
    let started = Instant::now();
    while bus.subscriber_count(topics::TopicId::Frames).unwrap() < 1 {
        assert!(started.elapsed() < Duration::from_secs(20), "no tracker");
        std::thread::sleep(Duration::from_millis(10));
    }
    let mut stdin = camera_py.0.stdin.take().unwrap();
    writeln!(stdin, "go").unwrap();
    let sent: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    assert_eq!(sent["pairs"], pairs, "{sent}");

    let mut got = Vec::new();
    while got.len() < pairs {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "{} of {pairs} frames' detections after 60 s",
            got.len()
        );
        match detections.receive().unwrap() {
            Some(d) => got.push(d),
            None => std::thread::sleep(Duration::from_millis(2)),
        }
    }
    let mut stage_stderr = stage.0.stderr.take().unwrap();
    tests::terminate(stage.0.id());
    let status = stage.0.wait().unwrap();
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut stage_stderr, &mut stderr).unwrap();
    assert!(status.success(), "{stderr}");
    drop(stdin);

    for (k, d) in got.iter().enumerate() {
        assert_eq!(d.seq, k as u64, "{stderr}");
        for cam in 0..2 {
            let found = &d.cameras[cam];
            let image =
                opencv::core::Mat::new_rows_cols_with_data(h, w, rendered[k].0[cam].as_slice())
                    .unwrap();
            let ours = detector.detect(&image).unwrap();
            let key = |id: u32, mirrored: u32, c: [f64; 2]| {
                (id, mirrored, (c[0] * 1e6) as i64, (c[1] * 1e6) as i64)
            };
            let mut expected: Vec<_> = ours
                .iter()
                .map(|m| key(m.id, m.mirrored, m.center))
                .collect();
            let mut seen: Vec<_> = found
                .iter()
                .map(|m| key(m.id, m.mirrored, m.center))
                .collect();
            expected.sort();
            seen.sort();
            assert_eq!(
                seen, expected,
                "frame {k} camera {cam}: the frame is not the image sent"
            );
            // And the markers the simulator drew are found where it drew them.
            for (id, mirrored, corners) in &rendered[k].1[cam] {
                let centre = corners.iter().sum::<nalgebra::Vector2<f64>>() / 4.0;
                let hit = found
                    .iter()
                    .find(|m| m.id == *id && (m.mirrored == 1) == *mirrored);
                let hit =
                    hit.unwrap_or_else(|| panic!("frame {k} camera {cam}: marker {id} not found"));
                let off = (nalgebra::Vector2::new(hit.center[0], hit.center[1]) - centre).norm();
                assert!(
                    off < 1.5,
                    "frame {k} camera {cam}: marker {id} {off} px off"
                );
            }
        }
    }
    assert!(
        rendered
            .iter()
            .all(|(_, m)| !m[0].is_empty() && !m[1].is_empty()),
        "every rendered pair shows a marker in both cameras"
    );

    let summary = std::fs::read_dir(&stats)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("ros2_camera")
        })
        .expect("the camera stage's stats");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(summary).unwrap()).unwrap();
    let count = |name: &str| {
        summary["counters"][name]
            .as_u64()
            .unwrap_or_else(|| panic!("{name}: {summary}"))
    };
    assert_eq!(count("pairs"), pairs as u64, "{summary}");
    assert_eq!(count("images_unpaired"), 1, "{summary}");
    assert_eq!(count("images_unsupported_encoding"), 1, "{summary}");
    assert_eq!(count("images_wrong_size"), 1, "{summary}");
    assert_eq!(count("images_malformed"), 1, "{summary}");
    assert_eq!(count("images"), 2 * pairs as u64 + 6, "{summary}");
    for named in [
        "\"yuv422\" is not supported",
        "the stream's frames are",
        "no attachment",
    ] {
        assert_eq!(stderr.matches(named).count(), 1, "{named}: {stderr}");
    }
    let latency = &summary["latencies"]["receive_to_publish"];
    eprintln!(
        "ros2 camera: {pairs} pairs, receive to publish p50 {} ms, p99 {} ms",
        latency["p50_ms"], latency["p99_ms"]
    );
}

/// `ros2_proc camera-info` writes a camera's `CameraInfo` (published by
/// Python with rosbags) as the calibration file the rig reads, with the
/// camera matrix and distortion as published; a lens model the rig cannot
/// use is refused in one line naming the topic, and no file is written.
#[test]
fn a_camera_info_becomes_the_rigs_calibration_file() {
    let dir = tempfile::tempdir().unwrap();
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut publisher = KillOnDrop(
        python("tests/ros2/image_publisher.py")
            .args(["--listen", &endpoint])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut lines = BufReader::new(publisher.0.stdout.take().unwrap()).lines();
    let ready: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    let published = &ready["left_info"];
    let fetch = |topic: &str, out: &Path| {
        Command::new(stage_binaries().join("ros2_proc"))
            .args(["camera-info", topic, "--endpoint", &endpoint])
            .args(["--out", out.to_str().unwrap()])
            .output()
            .unwrap()
    };
    let left = dir.path().join("left.yaml");
    let output = fetch("/left/camera_info", &left);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let (k, _) = formats::camera_file::read(&left).unwrap();
    let numbers = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let m = numbers(&published["k"]);
    assert_eq!(
        (k.width, k.height, k.fx, k.skew, k.cx, k.fy, k.cy),
        (640, 480, m[0], m[1], m[2], m[4], m[5])
    );
    assert_eq!(k.dist.coefficients(), numbers(&published["d"]));

    let fisheye = dir.path().join("fisheye.yaml");
    let output = fetch("/fisheye/camera_info", &fisheye);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    let last = stderr.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("ros2_proc: error: /fisheye/camera_info: ")
            && last.contains("unknown distortion model \"equidistant\""),
        "{stderr}"
    );
    assert!(!fisheye.exists());
    drop(publisher.0.stdin.take());
}

/// `replay export --ros2` writes `recording` as a bag in `bag`; rosbags
/// reads it (`tests/ros2/read_bag.py`), and its messages are the
/// recording's: every joint reading by the rig's joint names, every frame's
/// pixels (CRC-32), the rig's intrinsics, each calibration's frames on
/// `/tf_static` (offered TRANSIENT_LOCAL), each located object, all on the
/// wall clock through the offset the recorder noted.
fn bag_equals_recording(recording: &Path, bag: &Path) {
    use messages::topics::Message;
    let output = Command::new(stage_binaries().join("replay"))
        .args(["export", "--ros2"])
        .args([bag, recording])
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let out = python("tests/ros2/read_bag.py").arg(bag).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let read: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let topic = |name: &str| &read["topics"][name];

    let file = recorder::reader::Recording::open(recording).unwrap();
    let offset: i64 = file.extras().unwrap().metadata["run"]["wall_minus_monotonic_ns"]
        .parse()
        .unwrap();
    let rig = formats::rig::read(recording.with_file_name("rig.toml")).unwrap();
    let arm = rig.arm.as_ref().unwrap();
    let (mut positions, mut frames, mut calibrations, mut located) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    file.for_each(|_, m| {
        match m {
            Message::JointPositions(p) => positions.push(p),
            Message::Frames(h, pixels) => {
                let n = h.image_len();
                frames.push((
                    h.stamp_ns,
                    crc32fast::hash(&pixels[..n]),
                    crc32fast::hash(&pixels[n..2 * n]),
                ));
            }
            Message::Calibration(c) => calibrations.push(c),
            Message::Located(o) => located.push(o),
            _ => {}
        }
        Ok::<_, recorder::reader::ReadError>(true)
    })
    .unwrap();
    assert!(!positions.is_empty() && !frames.is_empty() && !calibrations.is_empty());

    let states = topic("/joint_states");
    assert_eq!(states["type"], "sensor_msgs/msg/JointState");
    assert_eq!(states["hash"], JointState::info().hash);
    assert_eq!(
        states["messages"].as_array().unwrap().len(),
        positions.len()
    );
    for (p, m) in positions.iter().zip(states["messages"].as_array().unwrap()) {
        assert_eq!(m["stamp"].as_i64().unwrap(), p.stamp_ns + offset);
        assert_eq!(m["name"], serde_json::json!(arm.joint_names()));
        let q: Vec<f64> = m["position"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(
            q,
            p.joints(),
            "the Nico arm's joints are revolute: rad both sides"
        );
    }
    for (k, name) in ["/left/image_raw", "/right/image_raw"].iter().enumerate() {
        let images = topic(name)["messages"].as_array().unwrap();
        assert_eq!(images.len(), frames.len(), "{name}");
        for (f, m) in frames.iter().zip(images) {
            assert_eq!(m["stamp"].as_i64().unwrap(), f.0 + offset);
            assert_eq!(m["encoding"], "mono8");
            assert_eq!(
                m["crc32"].as_u64().unwrap(),
                u64::from([f.1, f.2][k]),
                "{name}"
            );
        }
        let info = &topic(["/left/camera_info", "/right/camera_info"][k])["messages"][0];
        let i = rig.cameras[k].intrinsics;
        assert_eq!(
            info["k"],
            serde_json::json!([i.fx, i.skew, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0])
        );
        assert_eq!(info["d"], serde_json::json!(i.dist.coefficients()));
    }
    let tf = topic("/tf_static");
    assert_eq!(tf["durability"], serde_json::json!(["transient_local"]));
    let revisions = tf["messages"].as_array().unwrap();
    assert_eq!(revisions.len(), calibrations.len());
    let last = calibrations.last().unwrap();
    let mirror_cameras: Vec<_> = (0..2)
        .map(|k| last.cameras[k].to_camera(rig.cameras[k].intrinsics))
        .collect();
    let transforms = revisions.last().unwrap().as_array().unwrap();
    for (k, child) in ["mirror_camera_left", "mirror_camera_right"]
        .iter()
        .enumerate()
    {
        let t = transforms.iter().find(|t| t["child"] == *child).unwrap();
        assert_eq!(t["stamp"].as_i64().unwrap(), last.stamp_ns + offset);
        let expected = mirror_cameras[k].world_from_camera().translation.vector * 1e-3;
        let got: Vec<f64> = t["t"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert!((nalgebra::Vector3::new(got[0], got[1], got[2]) - expected).norm() < 1e-12);
    }
    let points = topic("/mirror/located")["messages"]
        .as_array()
        .map_or(0, Vec::len);
    assert_eq!(points, located.len());
    eprintln!(
        "bag: {} joint states, {} stereo frames, {} calibrations, {} located",
        positions.len(),
        frames.len(),
        calibrations.len(),
        located.len()
    );
}
