//! `recorder`: every topic of a running pipeline into one MCAP file.

use std::path::PathBuf;
use std::time::Duration;

use messages::topics::TopicId;
use runtime::Ports;
use serde::{Serialize, Serializer};

use crate::{Home, RestartPolicy, Side, Stage};

/// How much a live run's recorder gives way to the other stages: see
/// [`Recorder::niceness`](Stage::niceness).
pub const NICENESS: i32 = 10;

/// Chunk compression.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Compression {
    /// Zstandard (default): the best ratio at camera rates.
    #[default]
    Zstd,
    /// LZ4: faster, larger.
    Lz4,
    /// No compression.
    None,
}

/// Record a running pipeline into an MCAP file (until Ctrl-C / SIGTERM).
#[derive(Debug, Clone, PartialEq, Serialize, clap::Parser)]
#[command(version, about)]
pub struct Args {
    /// Service prefix of the pipeline to record.
    #[arg(long)]
    pub prefix: String,
    /// Output file.
    #[arg(long, default_value = "recording.mcap")]
    pub out: PathBuf,
    /// Replace the output file if it exists.
    #[arg(long)]
    pub overwrite: bool,
    /// Chunk compression.
    #[arg(long, value_enum, default_value_t = Compression::Zstd)]
    pub compression: Compression,
    /// Rig TOML: enables camera calibrations, camera frames and the arm in
    /// the viewing channels, and is stored as metadata and an attachment.
    #[arg(long)]
    pub rig: Option<PathBuf>,
    /// More files to attach (the pose plan, the pipeline config, ...).
    #[arg(long)]
    pub attach: Vec<PathBuf>,
    /// Extra metadata, KEY=VALUE (stored in the `run` metadata record).
    #[arg(long, value_parser = parse_key_value)]
    #[serde(serialize_with = "serialize_key_values")]
    pub meta: Vec<(String, String)>,
    /// Wait for the writer instead of dropping frames when it falls behind.
    #[arg(long)]
    pub no_drop: bool,
    /// Frames queued for the writer at most.
    #[arg(long, default_value_t = 64)]
    pub frame_queue: usize,
    /// Leave out the viewing image channels (the frames stay in the lossless channel).
    #[arg(long)]
    pub no_view_images: bool,
    /// Finish a chunk at least this often, ms (what a crash can lose).
    #[arg(long, default_value_t = 1000)]
    pub flush_ms: u64,
    /// Also serve the viewing channels live to Foxglove over WebSocket on this port of localhost.
    #[arg(long)]
    pub live_view: Option<u16>,
    /// With --live-view: serve on this address instead of 127.0.0.1 (logged
    /// as a warning: the Foxglove protocol has no authentication, so anyone
    /// who reaches it sees the run).
    #[arg(long, value_name = "ADDR", requires = "live_view")]
    pub live_view_bind: Option<std::net::IpAddr>,
    /// SCHED_FIFO priority (1-99) of the thread that takes messages out of
    /// shared memory, when the stages publishing them run at real-time
    /// priority (the launcher passes its base priority); compression and
    /// writing keep the process's priority.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=99))]
    pub realtime_priority: Option<u8>,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

impl Default for Args {
    fn default() -> Self {
        Self {
            prefix: "default".into(),
            out: "recording.mcap".into(),
            overwrite: false,
            compression: Compression::Zstd,
            rig: None,
            attach: Vec::new(),
            meta: Vec::new(),
            no_drop: false,
            frame_queue: 64,
            no_view_images: false,
            flush_ms: 1000,
            live_view: None,
            live_view_bind: None,
            realtime_priority: None,
            json: false,
        }
    }
}

fn parse_key_value(s: &str) -> Result<(String, String), String> {
    s.split_once('=')
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .ok_or_else(|| format!("`{s}`: expected KEY=VALUE"))
}

fn serialize_key_values<S: Serializer>(
    pairs: &[(String, String)],
    serializer: S,
) -> Result<S::Ok, S::Error> {
    serializer.collect_seq(pairs.iter().map(|(k, v)| format!("{k}={v}")))
}

/// The recorder's declaration.
pub struct Recorder;

impl Stage for Recorder {
    type Args = Args;
    const BINARY: &'static str = "recorder";
    const HOME: Home = Home::On(Side::Workstation);
    const SAMPLE_PATH_DEPTH: Option<u8> = None;
    /// A restart would overwrite its output; the run goes on without it.
    const RESTART: RestartPolicy = RestartPolicy::Optional;
    /// It takes what is waiting and finishes its file.
    const STOP_GRACE: Duration = Duration::from_secs(60);

    fn ports(_: &Args) -> Ports<'_> {
        Ports {
            subscribes: &TopicId::ALL,
            publishes: &[],
        }
    }

    fn prefix(args: &Args) -> &str {
        &args.prefix
    }

    fn example() -> Args {
        Args {
            prefix: "p_m0".into(),
            out: "out dir/recording.mcap".into(),
            overwrite: true,
            compression: Compression::Lz4,
            rig: Some("rig.toml".into()),
            attach: vec!["plan.csv".into(), "pipeline.toml".into()],
            meta: vec![("mirror".into(), "0".into()), ("run".into(), "a=b".into())],
            live_view: Some(8765),
            live_view_bind: Some(std::net::Ipv4Addr::UNSPECIFIED.into()),
            realtime_priority: Some(10),
            ..Default::default()
        }
    }

    /// A live run's recorder is the one stage no sample waits for: on a
    /// busy machine it gives way to the stages on the path from frame to
    /// sample, and its queue takes up the delay. A replay's recorder
    /// (`no_drop`) is on the replay's path, and must be subscribed to
    /// everything before the replayed messages come: it keeps the
    /// launcher's priority.
    fn niceness(args: &Args) -> i32 {
        if args.no_drop { 0 } else { NICENESS }
    }
}
