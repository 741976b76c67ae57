//! Two bridges over a zenoh TCP link on this host, between two service
//! prefixes (no shared memory in common between the sides' topics): joint
//! states and stereo frames cross byte for byte and in order; a message of
//! another layout put on the link is refused, counted and named in the log
//! with both layouts; both bridges stop cleanly on SIGTERM.

use std::net::TcpListener;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use messages::topics::{self, TopicId};
use messages::{Bus, Encoding, FrameHeader, JointState};
use tests::{KillOnDrop, stage_binaries, unique_prefix};
use zenoh::Wait;

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn bridge(args: &[&str]) -> KillOnDrop {
    KillOnDrop(
        Command::new(stage_binaries().join("bridge"))
            .args(args)
            .stderr(Stdio::piped())
            .spawn()
            .expect("the bridge starts"),
    )
}

/// SIGTERM, then the exit status and the log.
fn stop(mut child: KillOnDrop) -> (bool, String) {
    // SAFETY: kill(2) on our own child's pid.
    #[allow(unsafe_code)]
    unsafe {
        libc::kill(child.0.id() as i32, libc::SIGTERM);
    }
    let deadline = Instant::now() + Duration::from_secs(10);
    while child.0.try_wait().unwrap().is_none() {
        assert!(
            Instant::now() < deadline,
            "the bridge did not stop on SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let status = child.0.wait().unwrap();
    let mut log = String::new();
    use std::io::Read;
    child
        .0
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut log)
        .unwrap();
    (status.success(), log)
}

fn joint_state(seq: u64) -> JointState {
    JointState {
        seq,
        stamp_ns: 1_000 + seq as i64,
        pose: seq / 3,
        dof: 4,
        ..JointState::default()
    }
}

#[test]
fn topics_cross_between_prefixes_and_a_foreign_layout_is_refused() {
    let (robot, workstation) = (unique_prefix("bridge_robot"), unique_prefix("bridge_ws"));
    let namespace = format!("mirror/{robot}");
    let (robot_port, ws_port) = (free_port(), free_port());
    let robot_listen = format!("tcp/127.0.0.1:{robot_port}");
    let ws_listen = format!("tcp/127.0.0.1:{ws_port}");
    let sending = bridge(&[
        "--prefix",
        &robot,
        "--namespace",
        &namespace,
        "--send",
        "joint_state,frames",
        "--listen",
        &robot_listen,
    ]);
    let receiving = bridge(&[
        "--prefix",
        &workstation,
        "--namespace",
        &namespace,
        "--receive",
        "joint_state,frames",
        "--connect",
        &robot_listen,
        "--listen",
        &ws_listen,
    ]);

    let robot_bus = Bus::new(&robot, "test_robot").unwrap();
    let ws_bus = Bus::new(&workstation, "test_ws").unwrap();
    let joints_out = robot_bus.publisher::<topics::JointState>().unwrap();
    let joints_in = ws_bus.subscriber::<topics::JointState>().unwrap();
    let frames_in = ws_bus.frame_subscriber::<topics::Frames>().unwrap();
    let header = |seq: u64| FrameHeader {
        seq,
        stamp_ns: 5_000 + seq as i64,
        published_ns: 0,
        width: 32,
        height: 24,
        stride: 40,
        encoding: Encoding::Mono8 as u32,
    };
    let frames_out = robot_bus
        .frame_publisher::<topics::Frames>(2 * header(0).image_len())
        .unwrap();

    // The link comes up in its own time: probe (seq 0) until one crosses.
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        joints_out.send(joint_state(0)).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        if joints_in.receive().unwrap().is_some() {
            break;
        }
        assert!(Instant::now() < deadline, "no joint state crossed in 20 s");
    }
    while joints_in.receive().unwrap().is_some() {}

    // Joint states (sent reliably) all cross, in order, byte for byte.
    let n = 300;
    for seq in 1..=n {
        joints_out.send(joint_state(seq)).unwrap();
    }
    let mut got = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(10);
    while got.len() < n as usize && Instant::now() < deadline {
        match joints_in.receive().unwrap() {
            Some(js) if js.seq > 0 => got.push(js),
            Some(_) => {}
            None => std::thread::sleep(Duration::from_millis(2)),
        }
    }
    let sent: Vec<JointState> = (1..=n).map(joint_state).collect();
    assert_eq!(got.len(), sent.len(), "joint states lost on the link");
    assert!(
        got.iter()
            .zip(&sent)
            .all(|(a, b)| bytemuck::bytes_of(a) == bytemuck::bytes_of(b)),
        "joint states changed or reordered on the link"
    );

    // Frames: header and both images as published (published_ns kept).
    let pixels = |seq: u64, k: usize| -> Vec<u8> {
        (0..header(seq).image_len())
            .map(|i| (i * 7 + k * 13 + seq as usize) as u8)
            .collect()
    };
    let mut crossed = Vec::new();
    for seq in 1..=5u64 {
        frames_out
            .publish(header(seq), |l, r| {
                l.copy_from_slice(&pixels(seq, 0));
                r.copy_from_slice(&pixels(seq, 1));
                Ok::<_, std::convert::Infallible>(true)
            })
            .unwrap()
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            if let Some(frame) = frames_in.receive_with(|h, p| (*h, p.to_vec())).unwrap() {
                crossed.push(frame);
                break;
            }
            assert!(Instant::now() < deadline, "frame {seq} did not cross");
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    for (seq, (h, p)) in (1..=5u64).zip(&crossed) {
        assert_eq!(
            (h.seq, h.stamp_ns, h.width, h.height, h.stride),
            (seq, 5_000 + seq as i64, 32, 24, 40)
        );
        assert!(h.published_ns > 0, "the sender's publication time is kept");
        assert_eq!(p, &[pixels(seq, 0), pixels(seq, 1)].concat());
    }

    // A rogue peer puts a sample (another layout) on the joint-state key.
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", "\"peer\"").unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    config
        .insert_json5("connect/endpoints", &format!("[\"{ws_listen}\"]"))
        .unwrap();
    let rogue = zenoh::open(config).wait().unwrap();
    let foreign = bridge::envelope::seal(
        TopicId::Samples,
        0,
        bytemuck::bytes_of(&messages::MirrorSample::default()),
    );
    // Time for the rogue's link to come up, then for its message to arrive.
    std::thread::sleep(Duration::from_millis(500));
    rogue
        .put(format!("{namespace}/joint_state"), foreign)
        .wait()
        .unwrap();
    std::thread::sleep(Duration::from_millis(500));
    assert!(
        joints_in.receive().unwrap().is_none(),
        "the foreign message was published"
    );
    rogue.close().wait().unwrap();

    let (ok_send, _) = stop(sending);
    let (ok_receive, log) = stop(receiving);
    assert!(ok_send && ok_receive, "a bridge failed:\n{log}");
    let mismatch = format!(
        "layout mismatch on joint_state: the sender's is {}, this side's is {}",
        TopicId::Samples.layout().type_name,
        TopicId::JointState.layout().type_name
    );
    assert!(
        log.contains(&mismatch),
        "no refusal naming both layouts:\n{log}"
    );
    assert!(
        log.contains("refused=1"),
        "the refusal is not counted:\n{log}"
    );
    // Every joint state sent after the probes, and at least one probe.
    let count = |name: &str| -> u64 {
        let at = log
            .find(&format!("{name}="))
            .unwrap_or_else(|| panic!("no {name} in:\n{log}"));
        log[at + name.len() + 1..]
            .split(|c: char| !c.is_ascii_digit())
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    assert!(count("received_joint_state") > n, "{log}");
    assert_eq!(count("received_frames"), 5, "{log}");
}
