//! `bridge`: this side's topics to the other host of a split run, and the
//! other side's here, over zenoh.

use std::path::PathBuf;
use std::time::Duration;

use messages::topics::TopicId;
use runtime::Ports;
use serde::{Deserialize, Serialize};

use crate::{Home, RestartPolicy, Side, Stage};

/// How long the link may stay silent before it counts as cut, unless
/// `--lease-ms` says, ms.
pub const DEFAULT_LEASE_MS: u64 = 10_000;

/// What plain TCP exposes to a network, as the warning for `--insecure`
/// and the refusal without it name it.
pub const EXPOSED_ON_PLAIN_TCP: &str =
    "every message that crosses (camera frames, joint states, calibrations)";

/// How frames cross the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum FrameCompression {
    /// As in shared memory.
    #[default]
    None,
    /// Lossless zstd (level 1): about 3/4 of the bytes for 2 ms a frame.
    Zstd,
}

/// Carry pipeline topics between hosts: send topics from this host's shared
/// memory to a peer bridge over zenoh, and publish what it sends here.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Parser)]
#[command(version, about)]
pub struct Args {
    /// Service prefix of the pipeline on this host.
    #[arg(long)]
    pub prefix: String,
    /// First part of the zenoh keys; both sides must give the same (default
    /// `mirror/<prefix>`). A second robot on the same network uses another.
    #[arg(long)]
    pub namespace: Option<String>,
    /// Topics to send, comma-separated (e.g. `frames,joint_state`).
    #[arg(long, value_delimiter = ',', value_parser = crate::parse_topic)]
    #[serde(serialize_with = "crate::serialize_topics")]
    pub send: Vec<TopicId>,
    /// Topics to receive and publish here, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = crate::parse_topic)]
    #[serde(serialize_with = "crate::serialize_topics")]
    pub receive: Vec<TopicId>,
    /// Zenoh endpoint to listen on (repeatable), e.g. `tcp/0.0.0.0:7447`.
    #[arg(long)]
    pub listen: Vec<String>,
    /// Zenoh endpoint of the other side (repeatable), e.g. `tcp/10.0.0.2:7447`.
    #[arg(long)]
    pub connect: Vec<String>,
    /// How frames travel: `none` (as in shared memory) or `zstd`
    /// (lossless, level 1: for a link slower than the frames).
    #[arg(long, value_enum, default_value_t = FrameCompression::None)]
    pub compress_frames: FrameCompression,
    /// How long the link may stay silent before it counts as cut, ms; then
    /// the connecting side connects again by itself.
    #[arg(long, default_value_t = DEFAULT_LEASE_MS)]
    pub lease_ms: u64,
    /// The run's certificates (`pipeline certs --out DIR` makes them): the
    /// link is mutual TLS (`tls/` endpoints) as `--side`, and the other
    /// side may only send what this one receives and take what it sends.
    #[arg(long, value_name = "DIR", requires = "side")]
    pub certs: Option<PathBuf>,
    /// With --certs: which side's certificate this bridge holds.
    #[arg(long, value_enum, requires = "certs")]
    pub side: Option<Side>,
    /// Allow plain `tcp/` endpoints off loopback: anyone on the network
    /// can then read what crosses and send forged messages.
    #[arg(long)]
    pub insecure: bool,
}

/// The bridge's declaration.
pub struct Bridge;

impl Stage for Bridge {
    type Args = Args;
    const BINARY: &'static str = "bridge";
    const HOME: Home = Home::On(Side::Workstation);
    const SAMPLE_PATH_DEPTH: Option<u8> = Some(1);
    const RESTART: RestartPolicy = RestartPolicy::Service;
    /// It sends what is waiting.
    const STOP_GRACE: Duration = Duration::from_secs(10);

    /// It subscribes to what it sends and publishes what it receives.
    fn ports(args: &Args) -> Ports<'_> {
        Ports {
            subscribes: &args.send,
            publishes: &args.receive,
        }
    }

    fn prefix(args: &Args) -> &str {
        &args.prefix
    }

    fn example() -> Args {
        Args {
            prefix: "p".into(),
            namespace: Some("mirror/split/m0".into()),
            send: vec![TopicId::Frames, TopicId::JointState],
            receive: vec![TopicId::Calibration],
            listen: vec!["tls/0.0.0.0:7447".into()],
            connect: Vec::new(),
            compress_frames: FrameCompression::Zstd,
            lease_ms: 3000,
            certs: Some("certs".into()),
            side: Some(Side::Robot),
            insecure: false,
        }
    }
}
