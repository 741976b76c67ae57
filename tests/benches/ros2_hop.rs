//! What the ROS 2 arm stage adds to a joint state's trip, against a plain
//! zenoh subscriber's receive in the same run.
//!
//! A zenoh peer plays the robot (as `rmw_zenohd` and the controller would)
//! and publishes `sensor_msgs/JointState` at 200 Hz, each stamped with its
//! publication time and numbered in its first joint's position. Two clients
//! of it receive each sample:
//! - plain: a zenoh subscriber in this process (the transport alone);
//! - ours: `ros2_proc arm`, which checks the key's type hash and the
//!   attachment, decodes the CDR, maps the joints by name and publishes
//!   `joint_positions` into shared memory, taken here by a subscriber woken
//!   by its event.
//!
//! The added latency is ours less plain, at the median and the 99th
//! percentile. Run: `cargo bench -p tests --bench ros2_hop` (optimised
//! binaries; writes `target/bench/ros2_hop.json`); under `cargo test` a
//! short pass (200 samples), to check it works.

use std::collections::HashMap;
use std::ops::ControlFlow;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use messages::{now_ns, topics};
use ros2_proc::msgs::{Header, JointState, Time};
use ros2_proc::types::RosType;
use ros2_proc::wire::{self, Attachment};
use runtime::Bus;
use serde_json::json;
use tests::{KillOnDrop, unique_prefix};
use zenoh::Wait;

fn session(mode: &str, endpoints_key: &str, endpoint: &str) -> zenoh::Session {
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", &format!("{mode:?}")).unwrap();
    config
        .insert_json5(endpoints_key, &format!("[{endpoint:?}]"))
        .unwrap();
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    zenoh::open(config).wait().unwrap()
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Latencies (us) of the samples `received` saw, by number.
fn latencies(sent: &HashMap<i64, i64>, received: &[(i64, i64)]) -> Vec<f64> {
    let mut v: Vec<f64> = received
        .iter()
        .filter_map(|(n, at)| sent.get(n).map(|t| (at - t) as f64 / 1e3))
        .collect();
    v.sort_by(f64::total_cmp);
    v
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (bins, samples) = if full {
        (tests::release_stage_binaries(), 3000)
    } else {
        (tests::stage_binaries(), 200)
    };
    let dir = tempfile::tempdir().unwrap();
    let rig = dir.path().join("rig.toml");
    formats::rig::write(&rig, &geometry::sim::nico_scene().rig).unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let robot = session("peer", "listen/endpoints", &endpoint);
    let ty = JointState::info();
    let key = wire::topic_key(0, "/joint_states", &ty);

    // Plain: the transport alone.
    let plain_session = session("client", "connect/endpoints", &endpoint);
    let plain: Arc<Mutex<Vec<(i64, i64)>>> = Arc::default();
    let _plain_sub = {
        let plain = plain.clone();
        plain_session
            .declare_subscriber(key.clone())
            .callback(move |s| {
                let at = now_ns();
                if let Some(a) = s
                    .attachment()
                    .and_then(|a| Attachment::parse(&a.to_bytes()).ok())
                {
                    plain.lock().unwrap().push((a.sequence, at));
                }
            })
            .wait()
            .unwrap()
    };

    // Ours: the stage, and its joint positions out of shared memory.
    let prefix = unique_prefix("ros2_hop");
    let _stage = KillOnDrop(
        Command::new(bins.join("ros2_proc"))
            .args(["arm", "--prefix", &prefix, "--endpoint", &endpoint])
            .args(["--rig", rig.to_str().unwrap(), "--silent-ms", "10000"])
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let ours: Arc<Mutex<Vec<(i64, i64)>>> = Arc::default();
    let stop = Arc::new(AtomicBool::new(false));
    let taker = {
        let (ours, stop, prefix) = (ours.clone(), stop.clone(), prefix.clone());
        std::thread::spawn(move || {
            let bus = Bus::new(&prefix, "bench").unwrap();
            let positions = bus.subscriber::<topics::JointPositions>().unwrap();
            bus.wake()
                .unwrap()
                .run::<runtime::BusError>(
                    &[positions.listener()],
                    Some(Duration::from_millis(50)),
                    || {
                        while let Some(p) = positions.receive()? {
                            ours.lock().unwrap().push((p.q[0] as i64, now_ns()));
                        }
                        Ok(if stop.load(Ordering::Relaxed) {
                            ControlFlow::Break(())
                        } else {
                            ControlFlow::Continue(())
                        })
                    },
                )
                .unwrap();
        })
    };

    let publisher = robot.declare_publisher(key).wait().unwrap();
    let gid = [7u8; 16];
    let mut sent = HashMap::new();
    let publish = |n: i64| {
        let at = now_ns();
        let state = JointState {
            header: Header {
                stamp: Time::from_ns(ros2_proc::clock::to_wall(at)),
                frame_id: String::new(),
            },
            name: (1..=4).map(|j| format!("joint{j}")).collect(),
            position: vec![n as f64, 0.0, 0.0, 0.0],
            ..Default::default()
        };
        let attachment = Attachment {
            sequence: n,
            source_ns: ros2_proc::clock::wall_ns(),
            gid,
        };
        let payload = wire::encode(&state).unwrap();
        let at = now_ns();
        publisher
            .put(payload)
            .attachment(attachment.to_bytes().to_vec())
            .wait()
            .unwrap();
        at
    };
    // Until both have joined (negative numbers: not measured).
    let started = Instant::now();
    let mut warm = -1;
    while ours.lock().unwrap().is_empty() || plain.lock().unwrap().is_empty() {
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "ros2_proc arm did not join"
        );
        publish(warm);
        warm -= 1;
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(200));
    let period = Duration::from_millis(5);
    let mut next = Instant::now();
    for n in 1..=samples {
        sent.insert(n, publish(n));
        next += period;
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
    std::thread::sleep(Duration::from_millis(500));
    stop.store(true, Ordering::Relaxed);
    taker.join().unwrap();

    let plain = latencies(&sent, &plain.lock().unwrap());
    let ours = latencies(&sent, &ours.lock().unwrap());
    assert!(
        plain.len() as i64 >= samples * 9 / 10 && ours.len() as i64 >= samples * 9 / 10,
        "received {} plain, {} ours of {samples}",
        plain.len(),
        ours.len()
    );
    let row = |v: &[f64]| (percentile(v, 0.5), percentile(v, 0.99));
    let (p50, p99) = row(&plain);
    let (o50, o99) = row(&ours);
    println!(
        "ROS 2 joint state -> joint_positions, {samples} samples at 200 Hz, one host\n\
         {:<34} {:>6} {:>9} {:>9}\n\
         {:<34} {:>6} {:>9.1} {:>9.1}\n\
         {:<34} {:>6} {:>9.1} {:>9.1}\n\
         {:<34} {:>6} {:>9.1} {:>9.1}\n\
         ratio ours / plain at p50: {:.2}",
        "path",
        "count",
        "p50 us",
        "p99 us",
        "plain zenoh subscriber (baseline)",
        plain.len(),
        p50,
        p99,
        "ros2_proc arm -> shared memory",
        ours.len(),
        o50,
        o99,
        "added by the stage",
        "",
        o50 - p50,
        o99 - p99,
        o50 / p50
    );
    if full {
        let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/bench");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(
            out.join("ros2_hop.json"),
            serde_json::to_vec_pretty(&json!({
                "samples": samples,
                "plain": {"count": plain.len(), "p50_us": p50, "p99_us": p99},
                "ours": {"count": ours.len(), "p50_us": o50, "p99_us": o99},
                "added_p50_us": o50 - p50,
                "added_p99_us": o99 - p99,
            }))
            .unwrap(),
        )
        .unwrap();
    }
}
