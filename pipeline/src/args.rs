//! The launcher's command line.

use std::path::PathBuf;

use clap::Parser;
use mirror_proc::calibrate::Method;

use crate::split::{self, Side};

/// Run the live pipeline on the simulated robot.
#[derive(Debug, Parser)]
#[command(version, about, args_conflicts_with_subcommands = true)]
pub struct Args {
    /// Another task than running the pipeline.
    #[command(subcommand)]
    pub command: Option<Task>,
    /// Config file (TOML); see pipeline.toml.
    #[arg(long, default_value = "pipeline.toml")]
    pub config: PathBuf,
    /// Output directory.
    #[arg(long, default_value = "out/pipeline")]
    pub out: PathBuf,
    /// Mirror placements to run (overrides the config), e.g. 0,2.
    #[arg(long, value_delimiter = ',')]
    pub mirrors: Option<Vec<usize>>,
    /// Calibration poses per placement (overrides the config).
    #[arg(long)]
    pub poses: Option<usize>,
    /// Calibration method: paper, joint or joint+kinematics (overrides the config).
    #[arg(long)]
    pub method: Option<Method>,
    /// When the run ends, calibrate across its placements estimating the
    /// arm's base and/or tool too: base, tool or base,tool (overrides the
    /// config's `estimate`). One combined calibration goes into
    /// OUT/report.json.
    #[arg(long, value_name = "LIST")]
    pub estimate: Option<String>,
    /// Camera frame rate, Hz (overrides the config).
    #[arg(long)]
    pub fps: Option<f64>,
    /// The arm driver's command, instead of the simulated arm; the launcher
    /// appends `--prefix P --rig R` (overrides the config's `arm_driver`).
    /// E.g. "target/pyenv/bin/python python/examples/sim_arm.py".
    #[arg(long)]
    pub arm_driver: Option<String>,
    /// A ROS 2 robot on rmw_zenoh is the arm: the zenoh endpoint of its
    /// router (rmw_zenohd), e.g. tcp/robot.local:7447 (overrides the
    /// config's `[ros2] endpoint`; the rest of `[ros2]` applies).
    #[arg(long, value_name = "ENDPOINT")]
    pub ros2: Option<String>,
    /// Base SCHED_FIFO priority (1-97) of the stages every sample waits for:
    /// the tracker (and bridge) one above it, the simulated camera two, the
    /// kinematics three, the mirror stage four, the arm driver five (the
    /// heavy stage lowest, a camera's clock above it); 0: normal scheduling
    /// (overrides the config's `realtime_priority`, default 10).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=97))]
    pub realtime_priority: Option<u8>,
    /// Service prefix (default: unique per run).
    #[arg(long)]
    pub prefix: Option<String>,
    /// Do not record (by default each placement is recorded into
    /// `OUT/mirror<i>/recording.mcap`).
    #[arg(long)]
    pub no_record: bool,
    /// Serve the viewing channels live to Foxglove on this localhost port
    /// (ws://127.0.0.1:PORT) while the pipeline runs (the recorder serves
    /// them: not with --no-record).
    #[arg(long)]
    pub live_view: Option<u16>,
    /// With --live-view: the address to serve it on instead of 127.0.0.1,
    /// e.g. 0.0.0.0 for every interface. Anyone who reaches it sees the
    /// run: the Foxglove protocol has no authentication.
    #[arg(long, value_name = "ADDR", requires = "live_view")]
    pub live_view_bind: Option<std::net::IpAddr>,
    /// What to print at the end: the tables, or the whole report as JSON.
    #[arg(long, value_enum, default_value_t = ReportFormat::Table)]
    pub report: ReportFormat,
    /// Re-run the stages downstream of `--kind` on this recording (with the
    /// rig, plan and config it holds) instead of the simulated robot; the
    /// outputs go into OUT directly (`recording.mcap`, `report.json`, ...).
    #[arg(long, value_name = "FILE")]
    pub replay: Option<PathBuf>,
    /// With --replay: what to replay: `frames` re-runs the tracker and the
    /// mirror stage, `detections` the mirror stage.
    #[arg(long, value_enum, default_value_t = ReplayKind::Frames, requires = "replay")]
    pub kind: ReplayKind,
    /// Trace every stage step of every process into
    /// `OUT/mirror<i>/trace.json` (Chrome trace format; open it in Perfetto).
    #[arg(long)]
    pub trace: bool,
    /// Run one side of a run split across two hosts (both sides from the
    /// same config): `robot` starts the camera, the arm driver, kinematics
    /// and (unless the config's `split.tracker` offloads it) the tracker;
    /// `workstation` the mirror stage and the recorder. A `bridge` on each
    /// side carries the topics between them (see docs/bridge.md).
    #[arg(long, value_enum, requires = "endpoint")]
    pub side: Option<Side>,
    /// With --side: zenoh endpoint to listen on (repeatable), e.g.
    /// `tcp/0.0.0.0:7447` (typically on the robot).
    #[arg(long, group = "endpoint", requires = "side")]
    pub listen: Vec<String>,
    /// With --side: zenoh endpoint of the other side (repeatable), e.g.
    /// `tcp/192.168.1.20:7447` (typically on the workstation).
    #[arg(long, group = "endpoint", requires = "side")]
    pub connect: Vec<String>,
    /// With --side: the bridge's key namespace; both sides give the same,
    /// a second robot on the same network another.
    #[arg(long, default_value = split::DEFAULT_NAMESPACE, requires = "side")]
    pub namespace: String,
    /// With --side: the run's certificates (`pipeline certs` makes them; on
    /// each side its own and the CA's): the link is mutual TLS on `tls/`
    /// endpoints, and each side may only send its own topics (overrides the
    /// config's `split.certs`).
    #[arg(long, value_name = "DIR", requires = "side")]
    pub certs: Option<PathBuf>,
    /// With --side: allow a plain `tcp/` endpoint to or from another host.
    /// Anyone on that network can then read the run and send forged data.
    #[arg(long, requires = "side")]
    pub insecure: bool,
}

/// What `pipeline` can do besides running.
#[derive(Debug, clap::Subcommand)]
pub enum Task {
    /// Make the certificates of a run split across two hosts.
    Certs(crate::certs::CertsArgs),
}

/// What `--replay` publishes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ReplayKind {
    /// Frames and joint states: the tracker and the mirror stage re-run.
    Frames,
    /// Detections and joint states: the mirror stage re-runs.
    Detections,
}

impl ReplayKind {
    /// The replay's kind.
    pub fn kind(self) -> stages::replay::Kind {
        match self {
            ReplayKind::Frames => stages::replay::Kind::Frames,
            ReplayKind::Detections => stages::replay::Kind::Detections,
        }
    }
}

/// The form of the final report on stdout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ReportFormat {
    /// The paper's table and the latency table.
    Table,
    /// The full report (the same as OUT/report.json).
    Json,
}
