//! What the ROS 2 stages add to a message's trip, against a plain zenoh
//! subscriber's receive in the same run: the arm stage to a joint state,
//! the camera stage to a stereo image pair.
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
//!
//! Then the peer publishes stereo `sensor_msgs/Image` pairs (640x480, mono8
//! and rgb8) at 30 Hz, each pair numbered in its first pixels. Plain
//! receives both images; ours is `ros2_proc camera`, which pairs them by
//! stamp and writes them as one mono8 frame into shared memory, taken here
//! by a frame subscriber woken by its event. Both are timed from the
//! publication of the pair's second image.
//!
//! The added latency is ours less plain, at the median and the 99th
//! percentile. Run: `cargo bench -p tests --bench ros2_hop` (optimised
//! binaries; writes `target/bench/ros2_hop.json`); under `cargo test` a
//! short pass (200 joint states, 30 pairs), to check it works.

use std::collections::HashMap;
use std::ops::ControlFlow;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use messages::{now_ns, topics};
use ros2_proc::msgs::{Header, Image, JointState, Time};
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

/// Joint states at 200 Hz through `ros2_proc arm`; prints the table and
/// returns the figures.
fn joint_states(bins: &Path, samples: i64) -> serde_json::Value {
    let dir = tempfile::tempdir().unwrap();
    let rig = dir.path().join("rig.toml");
    formats::rig::write(&rig, &geometry::sim::nico_scene().rig).unwrap();
    let endpoint = format!("tcp/127.0.0.1:{}", tests::free_port());
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
    json!({
        "samples": samples,
        "plain": {"count": plain.len(), "p50_us": p50, "p99_us": p99},
        "ours": {"count": ours.len(), "p50_us": o50, "p99_us": o99},
        "added_p50_us": o50 - p50,
        "added_p99_us": o99 - p99,
    })
}

/// Stereo `Image` pairs of `encoding` at 30 Hz through `ros2_proc camera`;
/// prints the table and returns the figures.
fn image_pairs(bins: &Path, pairs: i64, encoding: &str) -> serde_json::Value {
    let (w, h) = (640usize, 480usize);
    let channels = if encoding == "mono8" { 1 } else { 3 };
    let endpoint = format!("tcp/127.0.0.1:{}", tests::free_port());
    let robot = session("peer", "listen/endpoints", &endpoint);
    let ty = Image::info();
    let keys = ["/left/image_raw", "/right/image_raw"].map(|t| wire::topic_key(0, t, &ty));

    // Plain: both images received; the pair counts when its right one is in.
    let plain_session = session("client", "connect/endpoints", &endpoint);
    let plain: Arc<Mutex<Vec<(i64, i64)>>> = Arc::default();
    let _plain_sub = {
        let plain = plain.clone();
        plain_session
            .declare_subscriber(keys[1].clone())
            .callback(move |s| {
                let at = now_ns();
                // The transport alone: the number read where it lies.
                let pieces = ros2_proc::image::Pieces::new(s.payload().slices());
                if let Ok(view) = ros2_proc::image::ImageView::parse_pieces(pieces) {
                    let mut first = [0u8; 6];
                    view.data.copy_to(0, &mut first[..2 * channels]);
                    plain.lock().unwrap().push((number(&first, channels), at));
                }
            })
            .wait()
            .unwrap()
    };
    let _plain_left = plain_session
        .declare_subscriber(keys[0].clone())
        .callback(|s| drop(s.payload().to_bytes()))
        .wait()
        .unwrap();

    let prefix = unique_prefix("ros2_camera_hop");
    let bus = Bus::new(&prefix, "bench").unwrap();
    let _services = bus.open_all().unwrap();
    let _stage = KillOnDrop(
        Command::new(bins.join("ros2_proc"))
            .args(["camera", "--prefix", &prefix, "--endpoint", &endpoint])
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
            let bus = Bus::new(&prefix, "bench_frames").unwrap();
            let frames = bus.frame_subscriber::<topics::Frames>().unwrap();
            bus.wake()
                .unwrap()
                .run::<runtime::BusError>(
                    &[frames.listener()],
                    Some(Duration::from_millis(50)),
                    || {
                        while let Some(n) = frames.receive_with(|_, data| number(data, 1))? {
                            ours.lock().unwrap().push((n, now_ns()));
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

    let publishers = keys.map(|k| robot.declare_publisher(k).wait().unwrap());
    let mut sequence = 0;
    let mut publish = |n: i64| {
        let stamp = ros2_proc::clock::wall_ns();
        let mut at = 0;
        for (eye, publisher) in publishers.iter().enumerate() {
            // The pair's number in its first pixels (grey in every channel).
            let mut data = vec![100u8; w * h * channels];
            let digits = [
                (n.rem_euclid(200)) as u8,
                (n.rem_euclid(40_000) / 200) as u8,
            ];
            for (k, d) in digits.iter().enumerate() {
                data[k * channels..(k + 1) * channels].fill(*d);
            }
            let image = Image {
                header: Header {
                    stamp: Time::from_ns(stamp),
                    frame_id: ["left", "right"][eye].into(),
                },
                height: h as u32,
                width: w as u32,
                encoding: encoding.into(),
                is_bigendian: 0,
                step: (w * channels) as u32,
                data,
            };
            sequence += 1;
            let attachment = Attachment {
                sequence,
                source_ns: ros2_proc::clock::wall_ns(),
                gid: [eye as u8; 16],
            };
            let payload = wire::encode(&image).unwrap();
            at = now_ns();
            publisher
                .put(payload)
                .attachment(attachment.to_bytes().to_vec())
                .wait()
                .unwrap();
        }
        at
    };
    let started = Instant::now();
    let mut warm = 39_999;
    while ours.lock().unwrap().is_empty() || plain.lock().unwrap().is_empty() {
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "ros2_proc camera did not join"
        );
        publish(warm);
        warm -= 1;
        std::thread::sleep(Duration::from_millis(33));
    }
    std::thread::sleep(Duration::from_millis(200));
    let period = Duration::from_micros(33_333);
    let mut sent = HashMap::new();
    let mut next = Instant::now();
    for n in 1..=pairs {
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
        plain.len() as i64 >= pairs * 9 / 10 && ours.len() as i64 >= pairs * 9 / 10,
        "received {} plain, {} ours of {pairs}",
        plain.len(),
        ours.len()
    );
    let (p50, p99) = (percentile(&plain, 0.5), percentile(&plain, 0.99));
    let (o50, o99) = (percentile(&ours, 0.5), percentile(&ours, 0.99));
    println!(
        "ROS 2 stereo Image pair ({w}x{h} {encoding}) -> frame in shared memory, {pairs} pairs at 30 Hz\n\
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
        "ros2_proc camera -> shared memory",
        ours.len(),
        o50,
        o99,
        "added by the stage",
        "",
        o50 - p50,
        o99 - p99,
        o50 / p50
    );
    json!({
        "pairs": pairs,
        "encoding": encoding,
        "plain": {"count": plain.len(), "p50_us": p50, "p99_us": p99},
        "ours": {"count": ours.len(), "p50_us": o50, "p99_us": o99},
        "added_p50_us": o50 - p50,
        "added_p99_us": o99 - p99,
    })
}

/// The pair number written in an image's first two pixels.
fn number(pixels: &[u8], channels: usize) -> i64 {
    i64::from(pixels[0]) + 200 * i64::from(pixels[channels])
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (bins, samples, pairs) = if full {
        (tests::release_stage_binaries(), 3000, 600)
    } else {
        (tests::stage_binaries(), 200, 30)
    };
    let figures = json!({
        "joint_states": joint_states(&bins, samples),
        "images_mono8": image_pairs(&bins, pairs, "mono8"),
        "images_rgb8": image_pairs(&bins, pairs, "rgb8"),
    });
    if full {
        let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/bench");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(
            out.join("ros2_hop.json"),
            serde_json::to_vec_pretty(&figures).unwrap(),
        )
        .unwrap();
    }
}
