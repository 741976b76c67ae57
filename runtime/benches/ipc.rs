//! One frame hop between two processes: iceoryx2 shared memory with event
//! wake-up (our `Bus`, as the camera and tracker use it) against a copying
//! baseline, a Unix domain socket carrying the same bytes (between two
//! threads: the kernel copies in and out the same way between processes),
//! in the same run.
//!
//! - Polled: the same hop with a receiver that spins on the subscriber
//!   instead of sleeping until the event, which shows the transfer alone,
//!   without the wake-up (the stages do not spin: two cores).
//! - Latency: one message at a time (1 ms apart), from the publisher's stamp
//!   to the subscriber holding the frame: publish-to-receive, one way, on
//!   the shared CLOCK_MONOTONIC. The zero-copy subscriber reads the frame in
//!   place; the socket's reader has to copy it into its buffer.
//! - Throughput: frames back to back, the shared-memory services created
//!   lossless (the publisher waits for the subscriber) like replay does.
//!
//! Payloads from 64 B to 8 MB (a stereo 640x480 mono frame is 600 KiB). The
//! publisher loans uninitialised memory, as the camera does (it renders over
//! every byte), so nothing in the hop grows with the payload.
//!
//! Run: `cargo bench -p runtime --bench ipc` (writes
//! `target/bench/ipc.json`); under `cargo test` a quick pass only.

use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::time::{Duration, Instant};

use hdrhistogram::Histogram;
use messages::{Encoding, FrameHeader, now_ns, topics};
use runtime::Bus;

/// Header of a frame whose two images total `bytes`.
fn header(seq: u64, bytes: usize) -> FrameHeader {
    let half = (bytes / 2) as u32;
    // Rows of at most 4096 bytes, as many as needed.
    let width = half.min(4096);
    FrameHeader {
        seq,
        stamp_ns: now_ns(),
        published_ns: 0, // set by publish
        width,
        height: half / width,
        stride: width,
        encoding: Encoding::Mono8 as u32,
    }
}

fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 10_000_000_000, 3).unwrap()
}

struct Figures {
    p50_us: f64,
    p99_us: f64,
    frames_per_s: f64,
}

/// The subscriber side, in its own process (this program run again with
/// `IPC_BENCH_RECEIVER=prefix,lossless,latency_n,total,poll`): prints the
/// p50 and p99 latency (us) and the stamp of the last frame received. With
/// `poll`, it spins on the subscriber instead of sleeping until the event.
fn receiver_process(spec: &str) {
    let parts: Vec<&str> = spec.split(',').collect();
    let (prefix, lossless) = (parts[0], parts[1] == "1");
    let latency_n: usize = parts[2].parse().unwrap();
    let total: usize = parts[3].parse().unwrap();
    let poll = parts[4] == "1";
    let bus = Bus::new(prefix, "ipc_sub").unwrap();
    let bus = if lossless { bus.lossless() } else { bus };
    let frames = bus.frame_subscriber::<topics::Frames>().unwrap();
    let mut latencies = histogram();
    let (mut received, mut last_ns) = (0usize, 0i64);
    let mut take = || {
        while let Some(stamp) = frames.receive_with(|h, _payload| h.stamp_ns).unwrap() {
            last_ns = now_ns();
            if received < latency_n {
                latencies
                    .record(((last_ns - stamp) / 1000).max(1) as u64)
                    .unwrap();
            }
            received += 1;
        }
        received < total
    };
    if poll {
        let deadline = Instant::now() + Duration::from_secs(60);
        while take() && Instant::now() < deadline {
            std::hint::spin_loop();
        }
    } else {
        bus.wake()
            .unwrap()
            .run(&[frames.listener()], Some(Duration::from_secs(10)), || {
                Ok::<_, runtime::BusError>(if take() {
                    std::ops::ControlFlow::Continue(())
                } else {
                    std::ops::ControlFlow::Break(())
                })
            })
            .unwrap();
    }
    println!(
        "{} {} {} {}",
        latencies.value_at_quantile(0.5),
        latencies.value_at_quantile(0.99),
        last_ns,
        received
    );
}

fn iceoryx2(
    bytes: usize,
    latency_n: usize,
    throughput_n: usize,
    lossless: bool,
    poll: bool,
    tag: &str,
) -> Figures {
    let prefix = format!("ipcbench{}_{tag}", std::process::id());
    let total = latency_n + throughput_n;
    let bus = Bus::new(&prefix, "ipc_pub").unwrap();
    let bus = if lossless { bus.lossless() } else { bus };
    let _services = bus.open_all().unwrap();
    let publisher = bus.frame_publisher::<topics::Frames>(bytes).unwrap();
    let child = std::process::Command::new(std::env::current_exe().unwrap())
        .env(
            "IPC_BENCH_RECEIVER",
            format!(
                "{prefix},{},{latency_n},{total},{}",
                u8::from(lossless),
                u8::from(poll)
            ),
        )
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    while bus.subscriber_count(topics::TopicId::Frames).unwrap() < 1 {
        std::thread::sleep(Duration::from_millis(1));
    }
    // Let the subscriber reach its wait.
    std::thread::sleep(Duration::from_millis(50));
    let send = |seq: u64| {
        publisher
            .publish(header(seq, bytes), |_, _| Ok::<_, ()>(true))
            .unwrap()
            .unwrap();
    };
    for seq in 0..latency_n as u64 {
        send(seq);
        std::thread::sleep(Duration::from_millis(1));
    }
    let started = now_ns();
    for seq in 0..throughput_n as u64 {
        send(latency_n as u64 + seq);
    }
    let output = child.wait_with_output().unwrap();
    let text = String::from_utf8(output.stdout).unwrap();
    let v: Vec<i64> = text
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    assert_eq!(v[3] as usize, total, "iceoryx2 lost frames");
    Figures {
        p50_us: v[0] as f64,
        p99_us: v[1] as f64,
        frames_per_s: throughput_n as f64 / ((v[2] - started) as f64 / 1e9),
    }
}

fn socket(bytes: usize, latency_n: usize, throughput_n: usize) -> Figures {
    let (mut tx, mut rx) = UnixStream::pair().unwrap();
    let total = latency_n + throughput_n;
    let receiver = std::thread::spawn(move || {
        let mut buf = vec![0u8; 8 + bytes];
        let mut latencies = histogram();
        let mut last_at = None;
        for i in 0..total {
            rx.read_exact(&mut buf).unwrap();
            let stamp = i64::from_le_bytes(buf[..8].try_into().unwrap());
            if i < latency_n {
                latencies
                    .record(((now_ns() - stamp) / 1000).max(1) as u64)
                    .unwrap();
            }
            last_at = Some(Instant::now());
        }
        (latencies, last_at)
    });
    // The frame already sits in the sender's memory (rendered there).
    let mut frame = vec![7u8; 8 + bytes];
    let mut send = |frame: &mut Vec<u8>| {
        frame[..8].copy_from_slice(&now_ns().to_le_bytes());
        tx.write_all(frame).unwrap();
    };
    for _ in 0..latency_n {
        send(&mut frame);
        std::thread::sleep(Duration::from_millis(1));
    }
    let started = Instant::now();
    for _ in 0..throughput_n {
        send(&mut frame);
    }
    let (latencies, last_at) = receiver.join().unwrap();
    Figures {
        p50_us: latencies.value_at_quantile(0.5) as f64,
        p99_us: latencies.value_at_quantile(0.99) as f64,
        frames_per_s: throughput_n as f64 / last_at.unwrap().duration_since(started).as_secs_f64(),
    }
}

fn main() {
    if let Ok(spec) = std::env::var("IPC_BENCH_RECEIVER") {
        return receiver_process(&spec);
    }
    let full = std::env::args().any(|a| a == "--bench");
    let sizes: &[usize] = if full {
        &[64, 4096, 65536, 614_400, 2 << 20, 8 << 20]
    } else {
        &[64, 614_400]
    };
    let (latency_n, throughput_n) = if full { (300, 300) } else { (10, 10) };
    println!(
        "frame hop between two processes, {latency_n} frames 1 ms apart for latency, {throughput_n} back to back for throughput"
    );
    println!(
        "  {:>9} | {:>10} {:>10} {:>10} | {:>10} | {:>10} {:>10} {:>10} | {:>8} {:>8} {:>8}",
        "payload",
        "shm p50 us",
        "p99 us",
        "frames/s",
        "polled p50",
        "uds p50 us",
        "p99 us",
        "frames/s",
        "p50 x",
        "polled x",
        "rate x"
    );
    let mut rows = Vec::new();
    for (k, &bytes) in sizes.iter().enumerate() {
        let shm = iceoryx2(bytes, latency_n, 0, false, false, &format!("l{k}"));
        let polled = iceoryx2(bytes, latency_n, 0, false, true, &format!("p{k}"));
        let shm_rate = iceoryx2(bytes, 0, throughput_n, true, false, &format!("t{k}"));
        let uds = socket(bytes, latency_n, throughput_n);
        let latency_ratio = uds.p50_us / shm.p50_us;
        let polled_ratio = uds.p50_us / polled.p50_us;
        let rate_ratio = shm_rate.frames_per_s / uds.frames_per_s;
        println!(
            "  {:>9} | {:>10.1} {:>10.1} {:>10.0} | {:>10.1} | {:>10.1} {:>10.1} {:>10.0} | {:>8.1} {:>8.1} {:>8.1}",
            bytes,
            shm.p50_us,
            shm.p99_us,
            shm_rate.frames_per_s,
            polled.p50_us,
            uds.p50_us,
            uds.p99_us,
            uds.frames_per_s,
            latency_ratio,
            polled_ratio,
            rate_ratio
        );
        rows.push(serde_json::json!({
            "bytes": bytes,
            "iceoryx2": { "p50_us": shm.p50_us, "p99_us": shm.p99_us, "frames_per_s": shm_rate.frames_per_s },
            "iceoryx2_polled": { "p50_us": polled.p50_us, "p99_us": polled.p99_us },
            "unix_socket": { "p50_us": uds.p50_us, "p99_us": uds.p99_us, "frames_per_s": uds.frames_per_s },
            "latency_ratio": latency_ratio,
            "polled_latency_ratio": polled_ratio,
            "throughput_ratio": rate_ratio,
        }));
    }
    if full {
        let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/bench");
        std::fs::create_dir_all(&out).unwrap();
        let path = out.join("ipc.json");
        std::fs::write(&path, serde_json::to_string_pretty(&rows).unwrap() + "\n").unwrap();
        println!("  figures: {}", path.display());
    }
}
