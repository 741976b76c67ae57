//! The link between hosts admits only the hosts that belong. Two bridges in
//! two network namespaces carry a robot's joint states and frames to a
//! workstation, which sends `located` back; a stranger on the network,
//! written with PyPI `eclipse-zenoh` only (`tests/bridge/stranger.py`),
//! tries what it can with what it holds:
//!
//! | the stranger holds | what happens |
//! |---|---|
//! | nothing, the link plain TCP (`--insecure`) | it reads the run, and a joint state it forges reaches the workstation's stages (the control: the test can fail) |
//! | nothing: plain TCP, or TLS without a client certificate | no session; nothing read |
//! | a certificate of another CA | no session; nothing read |
//! | the workstation's certificate, while the workstation runs | its joint states and frames on the robot's keys, in the right layout from the robot's own sender id, are denied by zenoh and reach no stage; what it may send (`located`) reaches the robot's bridge, which refuses it as malformed |
//! | the robot's certificate, against the robot | reads nothing; its forgeries reach no stage |
//! | the first robot's certificate, against a second robot's run | no session |
//!
//! Needs root (network namespaces); `MIRROR_SKIP_ROOT_TESTS=1` skips it.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use messages::topics::{self, TopicId};
use messages::{Encoding, FrameHeader, JointState};
use runtime::Bus;
use serde_json::Value;
use tests::hosts::{TwoHosts, skip_root_tests};
use tests::python::python_with_zenoh;
use tests::{KillOnDrop, stage_binaries, unique_prefix};

/// Sequence numbers from here on are the stranger's forgeries.
const FORGED: u64 = 1 << 40;

/// A bridge on one host, its log gathered as it runs.
struct Bridge {
    child: KillOnDrop,
    log: Arc<Mutex<String>>,
}

impl Bridge {
    fn start(hosts: &TwoHosts, k: usize, args: &[&str]) -> Bridge {
        let mut child = KillOnDrop(
            hosts
                .command(k, stage_binaries().join("bridge"))
                .args(args)
                .env("RUST_LOG", "info")
                .stderr(Stdio::piped())
                .spawn()
                .expect("ip netns exec starts"),
        );
        let log = Arc::new(Mutex::new(String::new()));
        let stderr = child.0.stderr.take().unwrap();
        let gathered = log.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                let mut log = gathered.lock().unwrap();
                log.push_str(&line);
                log.push('\n');
            }
        });
        Bridge { child, log }
    }

    fn log(&self) -> String {
        self.log.lock().unwrap().clone()
    }

    /// The bridge's zenoh id, once it logs that it is up.
    fn zid(&self) -> String {
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            let log = self.log();
            if let Some(at) = log.find("zid=") {
                return log[at + 4..]
                    .split(|c: char| !c.is_ascii_hexdigit())
                    .find(|s| !s.is_empty())
                    .unwrap()
                    .to_string();
            }
            assert!(Instant::now() < deadline, "the bridge is not up:\n{log}");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// SIGTERM, then its whole log.
    fn stop(mut self) -> String {
        // `ip netns exec` runs the bridge in its own process (it execs).
        tests::terminate(self.child.0.id());
        let _ = tests::wait_exit(&mut self.child.0, Duration::from_secs(15), "the bridge");
        std::thread::sleep(Duration::from_millis(100));
        self.log()
    }
}

/// The value of counter `name` in a bridge's log (its last ` name=N`).
fn counter(log: &str, name: &str) -> u64 {
    let Some(at) = log.rfind(&format!(" {name}=")) else {
        return 0;
    };
    log[at + name.len() + 2..]
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

/// `pipeline certs` into `dir`, the robot reached at `robot_host`.
fn make_certs(dir: &Path, robot_host: &str) -> PathBuf {
    let out = Command::new(stage_binaries().join("pipeline"))
        .args(["certs", "--out", dir.to_str().unwrap()])
        .args(["--robot-host", robot_host])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir.to_path_buf()
}

/// The stranger on host 1, connecting to `endpoint` with `credentials`
/// (stranger.py's options), reading `read` and forging `forge`.
fn stranger(
    hosts: &TwoHosts,
    endpoint: &str,
    credentials: &[String],
    read: &[String],
    forge: &[(String, PathBuf)],
) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("bridge/stranger.py");
    let mut command = hosts.command(1, python_with_zenoh());
    command
        .arg(script)
        .args(["--connect", endpoint])
        .args(credentials);
    for key in read {
        command.args(["--read", key]);
    }
    for (key, file) in forge {
        command
            .arg("--forge")
            .arg(format!("{key}={}", file.display()));
    }
    let started = Instant::now();
    let out = command.output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!(
        "stranger at {endpoint} {credentials:?}: {:.1} s: {}",
        started.elapsed().as_secs_f64(),
        stdout.trim()
    );
    serde_json::from_str(stdout.lines().last().unwrap_or_default()).unwrap_or_else(|e| {
        panic!(
            "stranger: {e}:\n{stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

fn credentials(dir: &Path, ca: bool, side: Option<&str>) -> Vec<String> {
    let mut args = Vec::new();
    if ca {
        args.extend(["--ca".into(), dir.join("ca.pem").display().to_string()]);
    }
    if let Some(side) = side {
        args.extend([
            "--cert".into(),
            dir.join(format!("{side}.pem")).display().to_string(),
            "--key".into(),
            dir.join(format!("{side}.key")).display().to_string(),
        ]);
    }
    args
}

/// What arrived on the workstation: joint-state and frame sequence numbers.
#[derive(Default)]
struct Arrived {
    joints: Vec<u64>,
    frames: Vec<u64>,
}

/// The robot's stages publishing joint states (250 Hz) and small frames
/// (20 Hz) under `robot`, and the workstation's taking them under
/// `workstation`, until dropped.
struct Traffic {
    stop: Arc<AtomicBool>,
    arrived: Arc<Mutex<Arrived>>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

fn frame_header(seq: u64) -> FrameHeader {
    FrameHeader {
        seq,
        stamp_ns: messages::now_ns(),
        published_ns: 0,
        width: 32,
        height: 24,
        stride: 32,
        encoding: Encoding::Mono8 as u32,
    }
}

fn joint_state(seq: u64) -> JointState {
    JointState {
        seq,
        stamp_ns: messages::now_ns(),
        pose: 0,
        dof: 4,
        ..JointState::default()
    }
}

impl Traffic {
    fn start(robot: &str, workstation: &str) -> Traffic {
        let stop = Arc::new(AtomicBool::new(false));
        let arrived = Arc::new(Mutex::new(Arrived::default()));
        let (robot, workstation) = (robot.to_string(), workstation.to_string());
        let publishing = {
            let stop = stop.clone();
            std::thread::spawn(move || {
                let bus = Bus::new(&robot, "test_robot").unwrap();
                let joints = bus.publisher::<topics::JointState>().unwrap();
                let frames = bus
                    .frame_publisher::<topics::Frames>(2 * frame_header(0).image_len())
                    .unwrap();
                let mut seq = 0;
                while !stop.load(Ordering::Relaxed) {
                    seq += 1;
                    joints.send(joint_state(seq)).unwrap();
                    if seq % 12 == 0 {
                        let _ = frames.publish(frame_header(seq / 12), |l, r| {
                            l.fill(1);
                            r.fill(2);
                            Ok::<_, std::convert::Infallible>(true)
                        });
                    }
                    std::thread::sleep(Duration::from_millis(4));
                }
            })
        };
        let taking = {
            let (stop, arrived) = (stop.clone(), arrived.clone());
            std::thread::spawn(move || {
                let bus = Bus::new(&workstation, "test_ws").unwrap();
                let joints = bus.subscriber::<topics::JointState>().unwrap();
                let frames = bus.frame_subscriber::<topics::Frames>().unwrap();
                while !stop.load(Ordering::Relaxed) {
                    while let Some(js) = joints.receive().unwrap() {
                        arrived.lock().unwrap().joints.push(js.seq);
                    }
                    while let Some(seq) = frames.receive_with(|h, _| h.seq).unwrap() {
                        arrived.lock().unwrap().frames.push(seq);
                    }
                    std::thread::sleep(Duration::from_millis(2));
                }
            })
        };
        Traffic {
            stop,
            arrived,
            threads: vec![publishing, taking],
        }
    }

    /// Waits until joint states and frames cross.
    fn wait_crossing(&self, logs: impl Fn() -> String) {
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            let a = self.arrived.lock().unwrap();
            if !a.joints.is_empty() && !a.frames.is_empty() {
                return;
            }
            drop(a);
            assert!(
                Instant::now() < deadline,
                "nothing crossed in 30 s:\n{}",
                logs()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Joint states and frames arrived so far: (all, forged).
    fn counts(&self) -> ((usize, usize), (usize, usize)) {
        let a = self.arrived.lock().unwrap();
        let forged = |v: &[u64]| v.iter().filter(|&&s| s >= FORGED).count();
        (
            (a.joints.len(), forged(&a.joints)),
            (a.frames.len(), forged(&a.frames)),
        )
    }
}

impl Drop for Traffic {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// The forgeries, written into `dir`: a joint state and a frame in the
/// right layout as from the robot's bridge `robot_zid` (numbered past
/// anything it sent), and junk on the workstation's `located` key.
fn forgeries(dir: &Path, namespace: &str, robot_zid: &str) -> Vec<(String, PathBuf)> {
    use bridge::envelope::{self, From};
    let from = From {
        sender: robot_zid,
        seq: FORGED,
        sent_ns: messages::now_ns(),
    };
    let header = frame_header(FORGED);
    let mut frame = bytemuck::bytes_of(&header).to_vec();
    frame.resize(frame.len() + 2 * header.image_len(), 7);
    let made = [
        (
            TopicId::JointState,
            bytemuck::bytes_of(&joint_state(FORGED)).to_vec(),
        ),
        (TopicId::Frames, frame),
    ];
    let mut files = Vec::new();
    for (topic, bytes) in made {
        let file = dir.join(format!("forged_{}", topic.name()));
        std::fs::write(
            &file,
            envelope::seal(topic, from, envelope::Encoding::Raw, &bytes),
        )
        .unwrap();
        files.push((format!("{namespace}/{}", topic.name()), file));
    }
    let junk = dir.join("junk");
    std::fs::write(&junk, b"not an envelope").unwrap();
    files.push((format!("{namespace}/located"), junk));
    files
}

/// The robot's and the workstation's bridges on hosts 0 and 1, the robot
/// listening at `endpoint`, with `security` (the bridge options of each).
fn bridges(
    hosts: &TwoHosts,
    namespace: &str,
    prefixes: (&str, &str),
    endpoint: &str,
    security: [&[&str]; 2],
) -> (Bridge, Bridge) {
    let robot = Bridge::start(
        hosts,
        0,
        &[
            &[
                "--prefix",
                prefixes.0,
                "--namespace",
                namespace,
                "--send",
                "joint_state,frames",
                "--receive",
                "located",
                "--listen",
                endpoint,
            ][..],
            security[0],
        ]
        .concat(),
    );
    let workstation = Bridge::start(
        hosts,
        1,
        &[
            &[
                "--prefix",
                prefixes.1,
                "--namespace",
                namespace,
                "--receive",
                "joint_state,frames",
                "--send",
                "located",
                "--connect",
                endpoint,
            ][..],
            security[1],
        ]
        .concat(),
    );
    (robot, workstation)
}

#[test]
fn only_the_runs_certificates_open_the_link_and_each_side_sends_only_its_own() {
    if skip_root_tests() {
        return;
    }
    let hosts = TwoHosts::new();
    let dir = tempfile::tempdir().unwrap();
    let robot_address = hosts.addresses[0].clone();
    let run = make_certs(&dir.path().join("run"), &robot_address);
    let other = make_certs(&dir.path().join("other"), &robot_address);
    let second = make_certs(&dir.path().join("second"), &robot_address);
    let keys = |namespace: &str| -> Vec<String> {
        ["joint_state", "frames"]
            .iter()
            .map(|t| format!("{namespace}/{t}"))
            .collect()
    };

    // The control: plain TCP, --insecure. The stranger with nothing reads
    // the run, and its forged joint state reaches the workstation's stages.
    {
        let (r, w) = (unique_prefix("open_r"), unique_prefix("open_w"));
        let namespace = format!("mirror/{r}");
        let endpoint = format!("tcp/{robot_address}:7447");
        let (robot, ws) = bridges(
            &hosts,
            &namespace,
            (&r, &w),
            &endpoint,
            [&["--insecure"], &["--insecure"]],
        );
        let traffic = Traffic::start(&r, &w);
        traffic.wait_crossing(|| format!("{}\n{}", robot.log(), ws.log()));
        let forged = forgeries(dir.path(), &namespace, &robot.zid());
        let seen = stranger(&hosts, &endpoint, &[], &keys(&namespace), &forged);
        assert_eq!(seen["opened"], true, "{seen}");
        assert!(
            seen["received"][&format!("{namespace}/joint_state")]
                .as_u64()
                .unwrap()
                > 0,
            "{seen}"
        );
        std::thread::sleep(Duration::from_millis(500));
        let ((_, forged_joints), _) = traffic.counts();
        drop(traffic);
        let (robot_log, ws_log) = (robot.stop(), ws.stop());
        assert!(
            robot_log.contains("--insecure") && robot_log.contains("plain TCP"),
            "the insecure link is warned about:\n{robot_log}"
        );
        assert!(
            forged_joints > 0,
            "on plain TCP the forged joint state should reach the workstation:\n{ws_log}"
        );
    }

    // Mutual TLS with the run's certificates and the access control.
    let (r, w) = (unique_prefix("tls_r"), unique_prefix("tls_w"));
    let namespace = format!("mirror/{r}");
    let endpoint = format!("tls/{robot_address}:7447");
    let (robot_side, ws_side) = (
        ["--certs", run.to_str().unwrap(), "--side", "robot"],
        ["--certs", run.to_str().unwrap(), "--side", "workstation"],
    );
    let (robot, ws) = bridges(
        &hosts,
        &namespace,
        (&r, &w),
        &endpoint,
        [&robot_side, &ws_side],
    );
    let traffic = Traffic::start(&r, &w);
    let logs = || format!("{}\n{}", robot.log(), ws.log());
    traffic.wait_crossing(logs);
    let forged = forgeries(dir.path(), &namespace, &robot.zid());
    let read = keys(&namespace);
    let no_session = |what: &str, seen: &Value| {
        assert_eq!(seen["opened"], false, "{what}: {seen}");
        assert_eq!(seen["bytes"], 0, "{what}: {seen}");
    };

    let plain = format!("tcp/{robot_address}:7447");
    no_session("plain TCP", &stranger(&hosts, &plain, &[], &read, &forged));
    no_session(
        "TLS without a client certificate",
        &stranger(
            &hosts,
            &endpoint,
            &credentials(&run, true, None),
            &read,
            &forged,
        ),
    );
    no_session(
        "a certificate of another CA",
        &stranger(
            &hosts,
            &endpoint,
            &[
                credentials(&run, true, None),
                credentials(&other, false, Some("workstation")),
            ]
            .concat(),
            &read,
            &forged,
        ),
    );
    let before = traffic.counts();
    let as_workstation = stranger(
        &hosts,
        &endpoint,
        &credentials(&run, true, Some("workstation")),
        &read,
        &forged,
    );
    assert_eq!(as_workstation["opened"], true, "{as_workstation}");
    assert!(as_workstation["put"].as_u64().unwrap() > 0);
    let as_robot = stranger(
        &hosts,
        &endpoint,
        &credentials(&run, true, Some("robot")),
        &read,
        &forged,
    );
    assert_eq!(as_robot["opened"], true, "{as_robot}");
    assert_eq!(
        as_robot["bytes"], 0,
        "the robot's certificate read: {as_robot}"
    );
    std::thread::sleep(Duration::from_millis(500));
    let after = traffic.counts();

    // A second robot's run, its own certificates and namespace.
    let r2 = unique_prefix("second_r");
    let second_ns = format!("mirror/{r2}");
    let second_endpoint = format!("tls/{robot_address}:7448");
    let second_robot = Bridge::start(
        &hosts,
        0,
        &[
            "--prefix",
            &r2,
            "--namespace",
            &second_ns,
            "--send",
            "joint_state",
            "--listen",
            &second_endpoint,
            "--certs",
            second.to_str().unwrap(),
            "--side",
            "robot",
        ],
    );
    second_robot.zid();
    no_session(
        "the first run's certificate against a second robot",
        &stranger(
            &hosts,
            &second_endpoint,
            &credentials(&run, true, Some("workstation")),
            &keys(&second_ns),
            &[],
        ),
    );
    second_robot.stop();

    drop(traffic);
    let (robot_log, ws_log) = (robot.stop(), ws.stop());
    let all = format!("--- robot:\n{robot_log}\n--- workstation:\n{ws_log}");
    // Not one forgery reached a stage, nor even the workstation's bridge
    // (which refuses nothing), while the genuine ones kept crossing.
    assert_eq!(after.0.1, 0, "a forged joint state arrived:\n{all}");
    assert_eq!(after.1.1, 0, "a forged frame arrived:\n{all}");
    assert!(after.0.0 > before.0.0 && after.1.0 > before.1.0, "{all}");
    assert_eq!(counter(&ws_log, "refused"), 0, "{all}");
    // What the workstation's certificate may send reaches the robot's
    // bridge, which refuses it as malformed: the link was open to it.
    assert!(counter(&robot_log, "refused") > 0, "{all}");
    assert!(!robot_log.contains("--insecure"), "{robot_log}");
    eprintln!(
        "as the workstation the stranger read {} messages ({} bytes) and put {}; \
         forged joint states and frames arrived: 0; the robot's bridge refused {} junk located",
        as_workstation["received"]
            .as_object()
            .map_or(0, |m| m.values().filter_map(Value::as_u64).sum::<u64>()),
        as_workstation["bytes"],
        as_workstation["put"],
        counter(&robot_log, "refused")
    );
}
