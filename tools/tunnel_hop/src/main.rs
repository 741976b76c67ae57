//! The hop through iceoryx2's zenoh tunnel (`iceoryx2-services-tunnel` with
//! `iceoryx2-integrations-zenoh-tunnel-backend`, 0.9.3), measured as
//! `tests/benches/hop.rs` measures our bridge: from publication into one
//! side's shared memory to being taken on the other's, at 200 messages/s,
//! for a small message and a stereo frame.
//!
//! Two "hosts" in one process: two iceoryx2 roots told apart by their
//! prefix, a tunnel on each, linked by zenoh over TCP on localhost. The
//! tunnel is a library that moves messages when it is called
//! (`discover()`, `propagate()`); its CLI calls it every `--poll` ms
//! (default 100; its reactive mode is not implemented in 0.9.3), so each
//! run here polls both tunnels at a given period, and the two tunnel
//! threads' CPU time is reported beside the latencies.
//!
//! Run: `cargo run --release --manifest-path tools/tunnel_hop/Cargo.toml`.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use iceoryx2_integrations_zenoh_tunnel_backend::ZenohBackend;
use iceoryx2_services_tunnel::{Config as TunnelConfig, Tunnel};

type Error = Box<dyn std::error::Error>;

/// An iceoryx2 root of its own: the files of `prefix` only.
fn side(prefix: &str) -> Result<Config, Error> {
    let mut config = Config::default();
    config.global.prefix = FileName::new(prefix.as_bytes())?;
    Ok(config)
}

fn zenoh_config(endpoint: &str, listen: bool) -> Result<zenoh::Config, Error> {
    let mut config = zenoh::Config::default();
    let set =
        |c: &mut zenoh::Config, k: &str, v: &str| c.insert_json5(k, v).map_err(|e| e.to_string());
    set(&mut config, "mode", "\"peer\"")?;
    set(&mut config, "scouting/multicast/enabled", "false")?;
    let key = if listen {
        "listen/endpoints"
    } else {
        "connect/endpoints"
    };
    set(&mut config, key, &format!("[\"{endpoint}\"]"))?;
    Ok(config)
}

/// A tunnel on `config`'s root, polled every `poll` until `stop`; returns
/// the CPU its thread used, as a share of one core over its life.
fn tunnel(
    config: Config,
    zenoh: zenoh::Config,
    poll: Duration,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<f64> {
    std::thread::spawn(move || {
        let (wall, cpu) = (Instant::now(), thread_cpu());
        let mut tunnel = Tunnel::<ipc::Service, ZenohBackend<ipc::Service>>::create(
            &TunnelConfig::default(),
            &config,
            &zenoh,
        )
        .expect("the tunnel starts");
        while !stop.load(Ordering::Relaxed) {
            let _ = tunnel.discover();
            let _ = tunnel.propagate();
            std::thread::sleep(poll);
        }
        (thread_cpu() - cpu).as_secs_f64() / wall.elapsed().as_secs_f64()
    })
}

/// This thread's CPU time.
fn thread_cpu() -> Duration {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime(2) fills the struct we own.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) };
    Duration::new(t.tv_sec as u64, t.tv_nsec as u32)
}

fn now_ns(base: Instant) -> u64 {
    base.elapsed().as_nanos() as u64
}

fn percentile(sorted: &[u64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i] as f64 * 1e-6
}

/// One payload size through two tunnels polled every `poll`.
fn measure(poll: Duration, size: usize, count: usize, run: usize) -> Result<(), Error> {
    let pid = std::process::id();
    let (a, b) = (format!("tha{pid}r{run}_"), format!("thb{pid}r{run}_"));
    let port = 17_000 + (pid % 20_000) as u16 + run as u16;
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let stop = Arc::new(AtomicBool::new(false));
    let tunnels = [
        tunnel(
            side(&a)?,
            zenoh_config(&endpoint, true)?,
            poll,
            stop.clone(),
        ),
        tunnel(
            side(&b)?,
            zenoh_config(&endpoint, false)?,
            poll,
            stop.clone(),
        ),
    ];
    let name = format!("hop/{size}");
    let base = Instant::now();
    let heard = Arc::new(AtomicBool::new(false));
    // The receiver on side b: the tunnel creates the service there once it
    // has heard of it from side a.
    let receiver = {
        let (config, name, heard, stop) = (side(&b)?, name.clone(), heard.clone(), stop.clone());
        std::thread::spawn(move || -> Vec<u64> {
            let node = NodeBuilder::new()
                .config(&config)
                .create::<ipc::Service>()
                .unwrap();
            let service_name: ServiceName = name.as_str().try_into().unwrap();
            let deadline = Instant::now() + Duration::from_secs(60);
            let service = loop {
                if let Ok(s) = node
                    .service_builder(&service_name)
                    .publish_subscribe::<[u8]>()
                    .open()
                {
                    break s;
                }
                assert!(
                    Instant::now() < deadline,
                    "the tunnel made no service on side b"
                );
                std::thread::sleep(Duration::from_millis(5));
            };
            let subscriber = service.subscriber_builder().create().unwrap();
            let mut latencies = Vec::new();
            while !stop.load(Ordering::Relaxed) {
                match subscriber.receive().unwrap() {
                    Some(sample) => {
                        let p = sample.payload();
                        let sent = u64::from_le_bytes(p[..8].try_into().unwrap());
                        heard.store(true, Ordering::Relaxed);
                        if p[8] == 1 {
                            latencies.push(now_ns(base) - sent);
                        }
                    }
                    None => std::thread::sleep(Duration::from_micros(20)),
                }
            }
            latencies
        })
    };
    let node = NodeBuilder::new()
        .config(&side(&a)?)
        .create::<ipc::Service>()?;
    let service = node
        .service_builder(&name.as_str().try_into()?)
        .publish_subscribe::<[u8]>()
        .subscriber_max_buffer_size(1024)
        .open_or_create()?;
    let publisher = service
        .publisher_builder()
        .initial_max_slice_len(size)
        .create()?;
    let mut payload = vec![7u8; size];
    let send = |payload: &mut Vec<u8>, measured: bool| -> Result<(), Error> {
        payload[..8].copy_from_slice(&now_ns(base).to_le_bytes());
        payload[8] = measured as u8;
        let sample = publisher.loan_slice_uninit(size)?;
        sample.write_from_slice(payload).send()?;
        Ok(())
    };
    // Probes until one crosses (the tunnels discover the service).
    let deadline = Instant::now() + Duration::from_secs(60);
    while !heard.load(Ordering::Relaxed) {
        send(&mut payload, false)?;
        std::thread::sleep(Duration::from_millis(10));
        if Instant::now() > deadline {
            return Err("nothing crossed the tunnel in 60 s".into());
        }
    }
    std::thread::sleep(poll * 3);
    for _ in 0..count {
        send(&mut payload, true)?;
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(poll * 3 + Duration::from_millis(200));
    stop.store(true, Ordering::Relaxed);
    let mut latencies = receiver.join().map_err(|_| "receiver panicked")?;
    let mut cpu = 0.0;
    for t in tunnels {
        cpu += t.join().map_err(|_| "tunnel panicked")?;
    }
    latencies.sort_unstable();
    if latencies.is_empty() {
        println!("| {} ms | {size} B | none arrived |", poll.as_millis());
        return Ok(());
    }
    println!(
        "| {} ms | {size} B | {:.2} | {:.2} | {}/{count} | {:.0}% |",
        poll.as_millis(),
        percentile(&latencies, 0.5),
        percentile(&latencies, 0.99),
        latencies.len(),
        100.0 * cpu
    );
    Ok(())
}

fn main() -> Result<(), Error> {
    println!(
        "| tunnel poll | payload | p50 ms | p99 ms | arrived | both tunnels' CPU (one core) |"
    );
    println!("|---|---|---|---|---|---|");
    let mut run = 0;
    for poll_ms in [100, 10, 1] {
        for size in [64, 2 * 640 * 480] {
            run += 1;
            let count = if poll_ms == 100 { 100 } else { 400 };
            measure(Duration::from_millis(poll_ms), size, count, run)?;
        }
    }
    Ok(())
}
