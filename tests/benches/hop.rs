//! The hop across the bridge against the local hop, per payload size.
//!
//! - Local hop: a frame published into shared memory and taken by a
//!   subscriber woken by its event, in this process (what every hop between
//!   two stages on one host is).
//! - Bridge hop: the same frame published on one prefix, carried by two
//!   `bridge` processes over zenoh TCP on this host, and taken on another
//!   prefix: shared memory, the sending bridge, the link, the receiving
//!   bridge, shared memory.
//!
//! - Bridge hop, compressed: the same with the bridges compressing frames
//!   (`--compress-frames zstd`).
//! - Bridge hop over TLS: the plain bridge hop on a mutual TLS link
//!   (`tls/`, the run's certificates, zenoh's access control on), as a
//!   split run between hosts has it by default; its ratios against the
//!   TCP hop are what the link's security costs.
//!
//! The pixels are a real photograph's (grey), so that compression sees
//! real texture. Latency is the taking time less the frame's publication time (the bridge
//! moves the latter onto the receiving clock: on one host its estimate is
//! off by microseconds, within the uncertainty the bridge logs), at 200
//! frames per second. Throughput is what arrives per second when the
//! publisher publishes as fast as it can for 2 s (frames are droppable on
//! both hops). Payloads are both images of a stereo frame, from 64 B to the
//! simulated head's 2 x 640 x 480.
//!
//! Run: `cargo bench -p tests --bench hop` (optimised bridges; writes
//! `target/bench/hop.json`); under `cargo test` a short pass (50 frames,
//! 0.5 s of flooding per size), to check it works.

use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use messages::topics;
use messages::{Encoding, FrameHeader, now_ns};
use runtime::Bus;
use serde_json::json;

/// Payload sizes (both images) and each image's width and height.
const SIZES: [(usize, u32, u32); 5] = [
    (64, 32, 1),
    (1024, 512, 1),
    (16 * 1024, 128, 64),
    (256 * 1024, 512, 256),
    (2 * 640 * 480, 640, 480),
];

struct Bridge(Child);

impl Drop for Bridge {
    fn drop(&mut self) {
        tests::terminate(self.0.id());
        let _ = self.0.wait();
    }
}

fn bridge(bins: &std::path::Path, args: &[&str]) -> Bridge {
    Bridge(
        Command::new(bins.join("bridge"))
            .args(args)
            .env("RUST_LOG", "warn")
            .stderr(Stdio::null())
            .spawn()
            .expect("the bridge starts"),
    )
}

fn header(seq: u64, width: u32, height: u32) -> FrameHeader {
    FrameHeader {
        seq,
        stamp_ns: now_ns(),
        published_ns: 0,
        width,
        height,
        stride: width,
        encoding: Encoding::Mono8 as u32,
    }
}

/// What one hop did at one size.
#[derive(Debug, Default)]
struct Measured {
    latencies_us: Vec<f64>,
    throughput_per_s: f64,
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Publishes on `from` and takes on `to`: `n` frames at 200 Hz, then as
/// fast as possible for `flood`.
fn measure(
    from: &str,
    to: &str,
    (size, w, h): (usize, u32, u32),
    n: usize,
    flood: Duration,
) -> Measured {
    let bus = Bus::new(from, "hop_out").unwrap();
    let publisher = bus.frame_publisher::<topics::Frames>(size).unwrap();
    let flags = (AtomicBool::new(false), AtomicBool::new(false));
    let (done, arrived) = (&flags.0, &flags.1);
    let pixels = photo_pixels(size / 2);
    std::thread::scope(|s| {
        let (ready_tx, ready) = crossbeam_channel::bounded(1);
        let taking = s.spawn(move || {
            let bus = Bus::new(to, "hop_in").unwrap();
            let subscriber = bus.frame_subscriber::<topics::Frames>().unwrap();
            ready_tx.send(()).unwrap();
            let mut arrivals: Vec<(u64, i64, i64)> = Vec::new();
            bus.wake()
                .unwrap()
                .run(
                    &[subscriber.listener()],
                    Some(Duration::from_millis(50)),
                    || {
                        while let Some(a) = subscriber
                            .receive_with(|h, p| (h.seq, h.published_ns, p.len()))
                            .unwrap()
                        {
                            assert_eq!(a.2, size, "payload size");
                            arrivals.push((a.0, a.1, now_ns()));
                            arrived.store(true, Ordering::Relaxed);
                        }
                        Ok::<_, runtime::BusError>(if done.load(Ordering::Relaxed) {
                            std::ops::ControlFlow::Break(())
                        } else {
                            std::ops::ControlFlow::Continue(())
                        })
                    },
                )
                .unwrap();
            arrivals
        });
        ready.recv().unwrap();
        let publish = |seq: u64| {
            publisher
                .publish(header(seq, w, h), |l, r| {
                    l.copy_from_slice(&pixels);
                    r.copy_from_slice(&pixels);
                    Ok::<_, std::convert::Infallible>(true)
                })
                .unwrap()
                .unwrap();
        };
        // Probes until the first arrives (the bridges' link may still be
        // coming up), then the measured frames.
        let deadline = Instant::now() + Duration::from_secs(30);
        let mut seq = 0;
        while !arrived.load(Ordering::Relaxed) {
            assert!(Instant::now() < deadline, "no frame arrived in 30 s");
            seq += 1;
            publish(seq);
            std::thread::sleep(Duration::from_millis(20));
        }
        std::thread::sleep(Duration::from_millis(300));
        let first_measured = 1_000_000;
        for k in 0..n as u64 {
            publish(first_measured + k);
            std::thread::sleep(Duration::from_millis(5));
        }
        std::thread::sleep(Duration::from_millis(300));
        let flood_from = 2_000_000;
        let began = Instant::now();
        let mut k = 0;
        while began.elapsed() < flood {
            publish(flood_from + k);
            k += 1;
        }
        std::thread::sleep(Duration::from_millis(500));
        done.store(true, Ordering::Relaxed);
        let arrivals = taking.join().unwrap();
        let mut latencies_us: Vec<f64> = arrivals
            .iter()
            .filter(|(s, ..)| (first_measured..flood_from).contains(s))
            .map(|(_, published, taken)| (taken - published) as f64 / 1e3)
            .collect();
        latencies_us.sort_by(f64::total_cmp);
        let flooded = arrivals.iter().filter(|(s, ..)| *s >= flood_from).count();
        Measured {
            latencies_us,
            throughput_per_s: flooded as f64 / flood.as_secs_f64(),
        }
    })
}

/// `n` grey pixels of a real photograph (repeated if it is smaller).
fn photo_pixels(n: usize) -> Vec<u8> {
    use opencv::prelude::*;
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/real_markers/eurobot/eurobot_01.jpg"
    );
    let image = opencv::imgcodecs::imread(path, opencv::imgcodecs::IMREAD_GRAYSCALE).unwrap();
    let bytes = image.data_bytes().unwrap();
    assert!(!bytes.is_empty(), "{path}: no image");
    bytes.iter().copied().cycle().take(n).collect()
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (bins, n, flood) = if full {
        (tests::release_stage_binaries(), 400, Duration::from_secs(2))
    } else {
        (tests::stage_binaries(), 50, Duration::from_millis(500))
    };
    // The local hop on a prefix of its own, which no bridge reads; each
    // pair of bridges between two prefixes of its own.
    let prefix = tests::unique_prefix;
    let local = prefix("hop_local");
    let certs = tempfile::tempdir().unwrap();
    let sides = ["robot", "workstation"].map(|name| secure_link::certs::SideRequest {
        name: name.into(),
        hosts: vec!["127.0.0.1".into()],
    });
    secure_link::certs::write(certs.path(), &sides, 1, false).unwrap();
    let certs = certs.path().to_str().unwrap();
    let pair = |name: &str, protocol: &str, extra: [&[&str]; 2]| {
        let (a, b) = (prefix(&format!("{name}_a")), prefix(&format!("{name}_b")));
        let port = tests::free_port();
        let endpoint = format!("{protocol}/127.0.0.1:{port}");
        let ns = format!("mirror/{a}");
        let common = ["--namespace", &ns];
        let sending = bridge(
            &bins,
            &[
                &common[..],
                extra[0],
                &["--prefix", &a, "--send", "frames", "--listen", &endpoint],
            ]
            .concat(),
        );
        let receiving = bridge(
            &bins,
            &[
                &common[..],
                extra[1],
                &[
                    "--prefix",
                    &b,
                    "--receive",
                    "frames",
                    "--connect",
                    &endpoint,
                ],
            ]
            .concat(),
        );
        (a, b, [sending, receiving])
    };
    let (a, b, _raw) = pair("hop", "tcp", [&[], &[]]);
    let zstd = ["--compress-frames", "zstd"];
    let (za, zb, _zstd) = pair("hopz", "tcp", [&zstd, &zstd]);
    let (ta, tb, _tls) = pair(
        "hopt",
        "tls",
        [
            &["--certs", certs, "--side", "robot"],
            &["--certs", certs, "--side", "workstation"],
        ],
    );
    println!(
        "{:>9} | {:>17} | {:>17} | {:>17} | {:>17} | {:>9} | {:>35} | {:>5} | {:>17}",
        "payload",
        "local p50/p99 us",
        "bridge p50/p99",
        "zstd p50/p99",
        "tls p50/p99",
        "p50 ratio",
        "frames/s local/bridge/zstd/tls",
        "zstd%",
        "tls/tcp p50 fps"
    );
    let mut rows = Vec::new();
    for size in SIZES {
        let local = measure(&local, &local, size, n, flood);
        let hop = measure(&a, &b, size, n, flood);
        let zhop = measure(&za, &zb, size, n, flood);
        let thop = measure(&ta, &tb, size, n, flood);
        let p = |m: &Measured| {
            (
                percentile(&m.latencies_us, 0.5),
                percentile(&m.latencies_us, 0.99),
            )
        };
        let ((l50, l99), (b50, b99), (z50, z99), (t50, t99)) =
            (p(&local), p(&hop), p(&zhop), p(&thop));
        let pixels = photo_pixels(size.0);
        let zstd_share = 100.0
            * zstd::bulk::compress(&pixels, bridge::envelope::ZSTD_LEVEL)
                .unwrap()
                .len() as f64
            / size.0 as f64;
        println!(
            "{:>9} | {:>8.0} {:>8.0} | {:>8.0} {:>8.0} | {:>8.0} {:>8.0} | {:>8.0} {:>8.0} | {:>9.1} | {:>8.0} {:>8.0} {:>8.0} {:>8.0} | {:>5.1} | {:>8.2} {:>8.2}",
            size.0,
            l50,
            l99,
            b50,
            b99,
            z50,
            z99,
            t50,
            t99,
            b50 / l50,
            local.throughput_per_s,
            hop.throughput_per_s,
            zhop.throughput_per_s,
            thop.throughput_per_s,
            zstd_share,
            t50 / b50,
            thop.throughput_per_s / hop.throughput_per_s
        );
        assert!(
            !hop.latencies_us.is_empty()
                && !zhop.latencies_us.is_empty()
                && !thop.latencies_us.is_empty(),
            "no frame of {} B crossed a bridge",
            size.0
        );
        rows.push(json!({
            "payload_bytes": size.0,
            "local": {"p50_us": l50, "p99_us": l99, "count": local.latencies_us.len(),
                      "frames_per_s": local.throughput_per_s,
                      "mb_per_s": local.throughput_per_s * size.0 as f64 / 1e6},
            "bridge": {"p50_us": b50, "p99_us": b99, "count": hop.latencies_us.len(),
                       "frames_per_s": hop.throughput_per_s,
                       "mb_per_s": hop.throughput_per_s * size.0 as f64 / 1e6},
            "bridge_zstd": {"p50_us": z50, "p99_us": z99, "count": zhop.latencies_us.len(),
                       "frames_per_s": zhop.throughput_per_s,
                       "mb_per_s": zhop.throughput_per_s * size.0 as f64 / 1e6,
                       "compressed_percent": zstd_share},
            "bridge_tls": {"p50_us": t50, "p99_us": t99, "count": thop.latencies_us.len(),
                       "frames_per_s": thop.throughput_per_s,
                       "mb_per_s": thop.throughput_per_s * size.0 as f64 / 1e6,
                       "p50_ratio_to_tcp": t50 / b50,
                       "throughput_ratio_to_tcp": thop.throughput_per_s / hop.throughput_per_s},
        }));
    }
    if full {
        let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/bench");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(
            out.join("hop.json"),
            serde_json::to_vec_pretty(&json!({"sizes": rows})).unwrap(),
        )
        .unwrap();
    }
}
