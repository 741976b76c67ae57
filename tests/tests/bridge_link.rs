//! Two bridges over a zenoh TCP link on this host, between two service
//! prefixes (no shared memory in common between the sides' topics), the
//! receiving one in a time namespace whose CLOCK_MONOTONIC is a day ahead
//! (as another host's would be): joint states and stereo frames cross in
//! order (frames compressed on the link), unchanged but for their times, which arrive on the receiving
//! side's clock; a message of another layout put on the link is refused,
//! counted and named in the log with both layouts; both bridges stop cleanly
//! on SIGTERM.
//!
//! Time namespaces need root (`unshare --time`), as the tests of two hosts
//! do; `MIRROR_SKIP_ROOT_TESTS=1` skips them, saying so.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use messages::topics::{self, TopicId};
use messages::{Encoding, FrameHeader, JointState};
use runtime::Bus;
use tests::hosts::{TwoHosts, skip_root_tests};
use tests::{KillOnDrop, free_port, stage_binaries, unique_prefix};
use zenoh::Wait;

/// How far ahead the receiving side's clock is: a day.
const AHEAD_S: i64 = 86_400;

fn bridge(args: &[&str]) -> KillOnDrop {
    KillOnDrop(
        Command::new(stage_binaries().join("bridge"))
            .args(args)
            .stderr(Stdio::piped())
            .spawn()
            .expect("the bridge starts"),
    )
}

/// A bridge whose CLOCK_MONOTONIC is `ahead_s` ahead of this process's.
fn bridge_ahead(ahead_s: i64, args: &[&str]) -> KillOnDrop {
    KillOnDrop(
        Command::new("unshare")
            .args(["--time", "--fork", "--kill-child=SIGTERM", "--monotonic"])
            .arg(ahead_s.to_string())
            .arg(stage_binaries().join("bridge"))
            .args(args)
            .stderr(Stdio::piped())
            .spawn()
            .expect("unshare starts"),
    )
}

/// SIGTERM to `child` (or to the process it forked, for `unshare`), then
/// the exit status and the log.
fn stop(mut child: KillOnDrop) -> (bool, String) {
    let pid = child.0.id();
    let forked = std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/children"))
        .ok()
        .and_then(|c| c.split_whitespace().next()?.parse::<i32>().ok());
    tests::terminate(forked.map_or(pid, |f| f as u32));
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
        stamp_ns: messages::now_ns() - 1_000_000 + seq as i64,
        pose: seq / 3,
        dof: 4,
        ..JointState::default()
    }
}

/// A zenoh peer of the test's own that `how` (`listen` or `connect`)s at
/// `endpoint`, without scouting.
fn zenoh_peer(how: &str, endpoint: &str) -> zenoh::Session {
    zenoh_open(how, endpoint).unwrap()
}

/// [`zenoh_peer`], or why it could not open.
fn zenoh_open(how: &str, endpoint: &str) -> zenoh::Result<zenoh::Session> {
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", "\"peer\"").unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    config
        .insert_json5(&format!("{how}/endpoints"), &format!("[\"{endpoint}\"]"))
        .unwrap();
    zenoh::open(config).wait()
}

/// `a` and `b` equal but for their stamps, and `b`'s stamp `a`'s moved by
/// `ahead_ns` within 5 ms.
fn same_but_moved(a: &JointState, b: &JointState, ahead_ns: i64) -> bool {
    let moved = JointState {
        stamp_ns: a.stamp_ns,
        ..*b
    };
    bytemuck::bytes_of(a) == bytemuck::bytes_of(&moved)
        && (b.stamp_ns - a.stamp_ns - ahead_ns).abs() < 5_000_000
}

#[test]
fn topics_cross_between_prefixes_and_a_foreign_layout_is_refused() {
    if skip_root_tests() {
        return;
    }
    let ahead_ns = AHEAD_S * 1_000_000_000;
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
        // Frames compressed on the link: they must still arrive unchanged.
        "--compress-frames",
        "zstd",
        "--listen",
        &robot_listen,
    ]);
    let receiving = bridge_ahead(
        AHEAD_S,
        &[
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
        ],
    );

    let robot_bus = Bus::new(&robot, "test_robot").unwrap();
    let ws_bus = Bus::new(&workstation, "test_ws").unwrap();
    let joints_out = robot_bus.publisher::<topics::JointState>().unwrap();
    let joints_in = ws_bus.subscriber::<topics::JointState>().unwrap();
    let frames_in = ws_bus.frame_subscriber::<topics::Frames>().unwrap();
    let start_ns = messages::now_ns();
    let header = |seq: u64| FrameHeader {
        seq,
        stamp_ns: start_ns + seq as i64,
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
    let sent: Vec<JointState> = (1..=n).map(joint_state).collect();
    for js in &sent {
        joints_out.send(*js).unwrap();
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
    assert_eq!(got.len(), sent.len(), "joint states lost on the link");
    for (a, b) in sent.iter().zip(&got) {
        assert!(
            same_but_moved(a, b, ahead_ns),
            "a joint state changed, reordered or not moved onto the receiving clock:\n{a:?}\n{b:?}"
        );
    }

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
        assert_eq!((h.seq, h.width, h.height, h.stride), (seq, 32, 24, 40));
        let moved = h.stamp_ns - (start_ns + seq as i64) - ahead_ns;
        assert!(
            moved.abs() < 5_000_000,
            "frame stamp moved wrong by {moved} ns"
        );
        // Published on the sending side (after the stamp), moved alike.
        assert!(
            h.published_ns - ahead_ns >= start_ns && h.published_ns < h.stamp_ns + 5_000_000_000,
            "{h:?}"
        );
        assert_eq!(p, &[pixels(seq, 0), pixels(seq, 1)].concat());
    }

    // A rogue peer puts a sample (another layout) on the joint-state key.
    let rogue = zenoh_peer("connect", &ws_listen);
    let foreign = bridge::envelope::seal(
        TopicId::Samples,
        bridge::envelope::From {
            sender: "0a",
            seq: 1,
            sent_ns: 0,
        },
        bridge::envelope::Encoding::Raw,
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
    // A message of the right layout from a made-up sender that answers no
    // round trip: its times cannot be moved onto this clock. Refused after
    // four unanswered trips (0.5 s each); the next one at once.
    let made_up = |seq: u64| {
        bridge::envelope::seal(
            TopicId::JointState,
            bridge::envelope::From {
                sender: "0b",
                seq,
                sent_ns: 0,
            },
            bridge::envelope::Encoding::Raw,
            bytemuck::bytes_of(&joint_state(seq)),
        )
    };
    for seq in 1..=2 {
        rogue
            .put(format!("{namespace}/joint_state"), made_up(seq))
            .wait()
            .unwrap();
    }
    std::thread::sleep(Duration::from_millis(3000));
    assert!(
        joints_in.receive().unwrap().is_none(),
        "a message from a sender without a clock offset was published"
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
        log.contains("no clock offset to 0b: it does not answer round trips"),
        "no refusal of the made-up sender:\n{log}"
    );
    assert!(
        log.contains("refused=3"),
        "the refusals are not counted:\n{log}"
    );
    // Every joint state sent after the probes, and at least one probe.
    let count = |name: &str| counter_in_log(&log, name);
    assert!(count("received_joint_state") > n, "{log}");
    assert_eq!(count("received_frames"), 5, "{log}");
    assert_eq!(count("lost_joint_state"), 0, "{log}");
    let logged_ahead: f64 = log
        .lines()
        .find(|l| l.contains("clock of a new sender"))
        .and_then(|l| l.split("ahead_s=").nth(1)?.split(' ').next()?.parse().ok())
        .unwrap_or_else(|| panic!("no clock offset in the log:\n{log}"));
    assert!(
        (logged_ahead + AHEAD_S as f64).abs() < 0.005,
        "the sender's clock is a day behind, not {logged_ahead} s"
    );
}

/// A bridge on host `k`.
fn bridge_on(hosts: &TwoHosts, k: usize, args: &[&str]) -> KillOnDrop {
    KillOnDrop(
        hosts
            .command(k, stage_binaries().join("bridge"))
            .args(args)
            .stderr(Stdio::piped())
            .spawn()
            .expect("ip netns exec starts"),
    )
}

/// The value of counter `name` in a stage's log (its first ` name=N`).
fn counter_in_log(log: &str, name: &str) -> u64 {
    let at = log
        .find(&format!(" {name}="))
        .unwrap_or_else(|| panic!("no {name} in:\n{log}"));
    log[at + name.len() + 2..]
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

#[test]
fn a_cut_link_comes_back_by_itself_and_both_sides_count_the_loss() {
    if skip_root_tests() {
        return;
    }
    let hosts = TwoHosts::new();
    let (robot, workstation) = (unique_prefix("cut_robot"), unique_prefix("cut_ws"));
    let namespace = format!("mirror/{robot}");
    // Over mutual TLS, as between hosts by default: the link comes back
    // through a new handshake.
    let listen = format!("tls/{}:7447", hosts.addresses[0]);
    let certs = tempfile::tempdir().unwrap();
    let sides = ["robot", "workstation"].map(|name| secure_link::certs::SideRequest {
        name: name.into(),
        hosts: vec![hosts.addresses[0].clone()],
    });
    secure_link::certs::write(certs.path(), &sides, 1, false).unwrap();
    let certs = certs.path().to_str().unwrap();
    // A short lease, so that a cut of 3 s is a cut and not a stall.
    let common = [
        "--namespace",
        &namespace,
        "--lease-ms",
        "1000",
        "--certs",
        certs,
    ];
    let sending = bridge_on(
        &hosts,
        0,
        &[
            &common[..],
            &[
                "--prefix",
                &robot,
                "--send",
                "joint_state",
                "--listen",
                &listen,
                "--side",
                "robot",
            ],
        ]
        .concat(),
    );
    let receiving = bridge_on(
        &hosts,
        1,
        &[
            &common[..],
            &[
                "--prefix",
                &workstation,
                "--receive",
                "joint_state",
                "--connect",
                &listen,
                "--side",
                "workstation",
            ],
        ]
        .concat(),
    );
    let robot_bus = Bus::new(&robot, "test_robot").unwrap();
    let ws_bus = Bus::new(&workstation, "test_ws").unwrap();
    let joints_out = robot_bus.publisher::<topics::JointState>().unwrap();
    let joints_in = ws_bus.subscriber::<topics::JointState>().unwrap();

    // 250 Hz: until the link is up, then 1 s, a cut of 3 s, and 3 s more.
    let mut arrived = Vec::new();
    let take = |arrived: &mut Vec<u64>| {
        while let Some(js) = joints_in.receive().unwrap() {
            arrived.push(js.seq);
        }
    };
    let mut seq = 0;
    let mut publish_for = |d: Duration, arrived: &mut Vec<u64>| {
        let until = Instant::now() + d;
        while Instant::now() < until {
            seq += 1;
            joints_out.send(joint_state(seq)).unwrap();
            std::thread::sleep(Duration::from_millis(4));
            take(arrived);
        }
        seq
    };
    let deadline = Instant::now() + Duration::from_secs(20);
    while arrived.is_empty() {
        assert!(
            Instant::now() < deadline,
            "the link did not come up in 20 s"
        );
        publish_for(Duration::from_millis(50), &mut arrived);
    }
    publish_for(Duration::from_secs(1), &mut arrived);
    hosts.link(false);
    let cut_at = publish_for(Duration::from_secs(3), &mut arrived);
    hosts.link(true);
    let last = publish_for(Duration::from_secs(3), &mut arrived);
    std::thread::sleep(Duration::from_millis(500));
    take(&mut arrived);

    let (ok_send, send_log) = stop(sending);
    let (ok_receive, log) = stop(receiving);
    assert!(ok_send && ok_receive, "a bridge failed:\n{send_log}\n{log}");
    // The link came back by itself: messages published after it did arrived.
    assert!(
        arrived.iter().any(|&s| s > cut_at) && arrived.last() == Some(&last),
        "nothing published after the cut arrived (last {:?} of {last}):\n{log}",
        arrived.last()
    );
    assert!(arrived.windows(2).all(|w| w[0] < w[1]), "reordered");
    // What never came is what the receiving side counts as lost.
    let first = arrived[0];
    let missing = (last - first + 1) - arrived.len() as u64;
    assert!(missing > 0, "a 3 s cut with a 1 s lease lost nothing");
    assert_eq!(counter_in_log(&log, "lost_joint_state"), missing, "{log}");
    // The sending side knows it spoke to no one for a while.
    assert!(
        counter_in_log(&send_log, "unheard_joint_state") > 0,
        "{send_log}"
    );
    eprintln!(
        "published {} after the first arrival, {missing} lost in the cut; sender: unheard {}, dropped {}",
        last - first + 1,
        counter_in_log(&send_log, "unheard_joint_state"),
        counter_in_log(&send_log, "dropped_joint_state")
    );
}

#[test]
fn a_second_robot_on_the_same_network_does_not_disturb_the_first() {
    // One zenoh network: each robot's bridge listens, and each workstation
    // bridge connects to both robots. Only the namespaces keep them apart.
    let prefix = |name: &str| unique_prefix(&format!("two_{name}"));
    let (robot1, robot2, ws1, ws2) = (prefix("r1"), prefix("r2"), prefix("w1"), prefix("w2"));
    let (ns1, ns2) = (format!("mirror/{robot1}"), format!("mirror/{robot2}"));
    let hubs = [free_port(), free_port()].map(|p| format!("tcp/127.0.0.1:{p}"));
    let robot = |prefix: &str, ns: &str, hub: &str| {
        bridge(&[
            "--prefix",
            prefix,
            "--namespace",
            ns,
            "--send",
            "joint_state",
            "--listen",
            hub,
        ])
    };
    let workstation = |prefix: &str, ns: &str| {
        bridge(&[
            "--prefix",
            prefix,
            "--namespace",
            ns,
            "--receive",
            "joint_state",
            "--connect",
            &hubs[0],
            "--connect",
            &hubs[1],
        ])
    };
    let first_robot = robot(&robot1, &ns1, &hubs[0]);
    let first_ws = workstation(&ws1, &ns1);
    let second_ws = workstation(&ws2, &ns2);

    let marked = |robot: u64, seq: u64| JointState {
        pose: robot,
        ..joint_state(seq)
    };
    let out1 = Bus::new(&robot1, "test_r1")
        .unwrap()
        .publisher::<topics::JointState>()
        .unwrap();
    let bus_r2 = Bus::new(&robot2, "test_r2").unwrap();
    let out2 = bus_r2.publisher::<topics::JointState>().unwrap();
    let in1 = Bus::new(&ws1, "test_w1")
        .unwrap()
        .subscriber::<topics::JointState>()
        .unwrap();
    let in2 = Bus::new(&ws2, "test_w2")
        .unwrap()
        .subscriber::<topics::JointState>()
        .unwrap();
    let (mut got1, mut got2) = (Vec::new(), Vec::new());
    let take = |got1: &mut Vec<JointState>, got2: &mut Vec<JointState>| {
        while let Some(js) = in1.receive().unwrap() {
            got1.push(js);
        }
        while let Some(js) = in2.receive().unwrap() {
            got2.push(js);
        }
    };
    // The first robot's link comes up.
    let deadline = Instant::now() + Duration::from_secs(20);
    while got1.is_empty() {
        assert!(
            Instant::now() < deadline,
            "the first robot's link did not come up"
        );
        out1.send(marked(1, 0)).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        take(&mut got1, &mut got2);
    }
    // The first robot streams at 250 Hz while the second joins, streams and
    // leaves.
    let mut second_robot = None;
    for seq in 1..=1000u64 {
        out1.send(marked(1, seq)).unwrap();
        match seq {
            100 => second_robot = Some(robot(&robot2, &ns2, &hubs[1])),
            300..=700 => out2.send(marked(2, seq)).unwrap(),
            800 => {
                let (ok, log) = stop(second_robot.take().unwrap());
                assert!(ok, "the second robot's bridge failed:\n{log}");
            }
            _ => {}
        }
        std::thread::sleep(Duration::from_millis(4));
        take(&mut got1, &mut got2);
    }
    std::thread::sleep(Duration::from_millis(500));
    take(&mut got1, &mut got2);

    let (ok1, _) = stop(first_robot);
    let (ok_ws1, log1) = stop(first_ws);
    let (ok_ws2, log2) = stop(second_ws);
    assert!(ok1 && ok_ws1 && ok_ws2, "a bridge failed:\n{log1}\n{log2}");
    // Each workstation side has its own robot's messages only.
    assert!(
        got1.iter().all(|js| js.pose == 1),
        "the second robot's messages reached the first's side"
    );
    assert!(
        got2.iter().all(|js| js.pose == 2),
        "the first robot's messages reached the second's side"
    );
    // The first robot's stream lost nothing and kept its order.
    let after_probes: Vec<u64> = got1.iter().map(|js| js.seq).filter(|&s| s > 0).collect();
    assert_eq!(
        after_probes,
        (1..=1000).collect::<Vec<_>>(),
        "the first robot's stream was disturbed"
    );
    assert_eq!(counter_in_log(&log1, "lost_joint_state"), 0, "{log1}");
    // The second robot's messages crossed too, from when its link was up
    // (the workstation side connects again every 1 to 4 s) to its last.
    assert!(
        got2.last().is_some_and(|js| js.seq == 700) && got2.windows(2).all(|w| w[0].seq < w[1].seq),
        "{} of the second robot's 401 messages crossed:\n{log2}",
        got2.len()
    );
    drop(bus_r2);
}

/// The sending side checks the receivers' layouts before it takes anything
/// from shared memory: a receiver that takes joint states in another layout
/// (a build of another version on the other host) stops the sending bridge
/// with both layout names, before it has sent anything.
#[test]
fn a_receiver_of_another_layout_is_named_by_the_sender_before_it_sends() {
    let robot = unique_prefix("layout_robot");
    let namespace = format!("mirror/{robot}");
    // A port checked free was taken before this peer could listen on it,
    // in two CI runs: another port then.
    let (other, listen) = (0..5)
        .find_map(|_| {
            let listen = format!("tcp/127.0.0.1:{}", free_port());
            zenoh_open("listen", &listen)
                .map_err(|e| eprintln!("listening at {listen}: {e}"))
                .ok()
                .map(|s| (s, listen))
        })
        .expect("no port to listen on in 5 tries");
    let _receiver = other
        .declare_subscriber(format!("{namespace}/joint_state"))
        .callback(|_| {})
        .wait()
        .unwrap();
    let layout_key = format!("{namespace}/_layout/joint_state/0c");
    let answer_key = layout_key.clone();
    let _layout = other
        .declare_queryable(layout_key)
        .callback(move |query| {
            let _ = query
                .reply(answer_key.as_str(), "mirror.JointState.v9")
                .wait();
        })
        .wait()
        .unwrap();
    let mut sending = bridge(&[
        "--prefix",
        &robot,
        "--namespace",
        &namespace,
        "--send",
        "joint_state",
        "--connect",
        &listen,
    ]);
    let deadline = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(status) = sending.0.try_wait().unwrap() {
            break status;
        }
        assert!(Instant::now() < deadline, "the sending bridge did not stop");
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut log = String::new();
    use std::io::Read;
    sending
        .0
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut log)
        .unwrap();
    assert!(!status.success(), "{log}");
    assert!(
        log.contains(
            "layout mismatch on joint_state: this side's is mirror.JointState.v1, \
             the receiver 0c's is mirror.JointState.v9"
        ),
        "{log}"
    );
    assert!(log.contains("sent_joint_state=0"), "{log}");
}
