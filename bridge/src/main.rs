//! `bridge`: carries pipeline topics between this host and another over
//! zenoh (see the library's documentation).

use std::process::ExitCode;
use std::sync::atomic::AtomicBool;

use anyhow::{Result, anyhow};
use bridge::{Counters, Options};
use clap::Parser;
use messages::topics::TopicId;

/// Carry pipeline topics between hosts: send topics from this host's shared
/// memory to a peer bridge over zenoh, and publish what it sends here.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    /// Service prefix of the pipeline on this host.
    #[arg(long)]
    prefix: String,
    /// First part of the zenoh keys; both sides must give the same (default
    /// `mirror/<prefix>`). A second robot on the same network uses another.
    #[arg(long)]
    namespace: Option<String>,
    /// Topics to send, comma-separated (e.g. `frames,joint_state`).
    #[arg(long, value_delimiter = ',', value_parser = topic)]
    send: Vec<TopicId>,
    /// Topics to receive and publish here, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = topic)]
    receive: Vec<TopicId>,
    /// Zenoh endpoint to listen on (repeatable), e.g. `tcp/0.0.0.0:7447`.
    #[arg(long)]
    listen: Vec<String>,
    /// Zenoh endpoint of the other side (repeatable), e.g. `tcp/10.0.0.2:7447`.
    #[arg(long)]
    connect: Vec<String>,
    /// How frames travel: `none` (as in shared memory) or `zstd`
    /// (lossless, level 1: for a link slower than the frames).
    #[arg(long, value_parser = ["none", "zstd"], default_value = "none")]
    compress_frames: String,
    /// How long the link may stay silent before it counts as cut, ms; then
    /// the connecting side connects again by itself.
    #[arg(long, default_value_t = bridge::DEFAULT_LEASE_MS)]
    lease_ms: u64,
}

fn topic(name: &str) -> Result<TopicId> {
    TopicId::from_name(name).ok_or_else(|| {
        let known: Vec<_> = TopicId::ALL.iter().map(|t| t.name()).collect();
        anyhow!("no topic {name:?} (topics: {})", known.join(", "))
    })
}

fn run(args: Args) -> Result<()> {
    let options = Options {
        namespace: args
            .namespace
            .unwrap_or_else(|| format!("mirror/{}", args.prefix)),
        prefix: args.prefix,
        send: args.send,
        receive: args.receive,
        listen: args.listen,
        connect: args.connect,
        lease_ms: args.lease_ms,
        frame_encoding: if args.compress_frames == "zstd" {
            bridge::envelope::Encoding::Zstd
        } else {
            bridge::envelope::Encoding::Raw
        },
    };
    let counters = Counters::default();
    let stop = AtomicBool::new(false);
    let result = bridge::run(&options, &counters, &stop);
    counters.into_stats(&options).finish();
    result
}

fn main() -> ExitCode {
    messages::stage_main("bridge", || run(Args::parse()))
}
