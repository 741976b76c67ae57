//! `pipeline`: runs the whole live pipeline on the simulated robot, one
//! mirror placement after another, and prints the paper's table for the run.
//!
//! Per placement it writes `rig.toml` and `plan.csv` into `OUT/mirror<i>/`,
//! starts the stages from their specs ([`stages`]): `recorder` (unless
//! `--no-record`), `mirror_proc`, `tracker_proc`, `camera_proc` and the arm
//! driver (`sim_arm`, or `--arm-driver`), waits until they are subscribed,
//! then starts `kinematics_proc` on the plan ([`supervise`]). A stage that crashes is restarted as its policy says.
//! When the plan is done `mirror_proc` writes `report.json`; the launcher
//! stops the rest, evaluates the calibration against the simulator's truth
//! and writes `OUT/report.json` ([`report`]). Ctrl-C stops every stage
//! cleanly. With `--side robot|workstation` it runs one side of a run split
//! across two hosts, with a `bridge` to the other ([`split`]).

mod config;
mod replay;
mod report;
mod run;
mod scheduling;
mod split;
mod supervise;

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use clap::Parser;
use mirror_proc::calibrate::Method;
use mirror_proc::experiment::PAPER_FIGURES;

use crate::config::{Config, Overrides};
use crate::run::Run;
use crate::split::{Link, Side};

/// Run the live pipeline on the simulated robot.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    /// Config file (TOML); see pipeline.toml.
    #[arg(long, default_value = "pipeline.toml")]
    config: PathBuf,
    /// Output directory.
    #[arg(long, default_value = "out/pipeline")]
    out: PathBuf,
    /// Mirror placements to run (overrides the config), e.g. 0,2.
    #[arg(long, value_delimiter = ',')]
    mirrors: Option<Vec<usize>>,
    /// Calibration poses per placement (overrides the config).
    #[arg(long)]
    poses: Option<usize>,
    /// Calibration method: paper, joint or joint+kinematics (overrides the config).
    #[arg(long)]
    method: Option<Method>,
    /// Camera frame rate, Hz (overrides the config).
    #[arg(long)]
    fps: Option<f64>,
    /// The arm driver's command, instead of the simulated arm; the launcher
    /// appends `--prefix P --rig R` (overrides the config's `arm_driver`).
    /// E.g. "target/pyenv/bin/python python/examples/sim_arm.py".
    #[arg(long)]
    arm_driver: Option<String>,
    /// Base SCHED_FIFO priority (1-97) of the stages every sample waits for:
    /// the camera and arm driver at it, the tracker, kinematics (and bridge)
    /// one above, the mirror stage two above; 0: normal scheduling
    /// (overrides the config's `realtime_priority`, default 10).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=97))]
    realtime_priority: Option<u8>,
    /// Service prefix (default: unique per run).
    #[arg(long)]
    prefix: Option<String>,
    /// Do not record (by default each placement is recorded into
    /// `OUT/mirror<i>/recording.mcap`).
    #[arg(long)]
    no_record: bool,
    /// Serve the viewing channels live to Foxglove on this localhost port
    /// (ws://127.0.0.1:PORT) while the pipeline runs (the recorder serves
    /// them: not with --no-record).
    #[arg(long)]
    live_view: Option<u16>,
    /// What to print at the end: the tables, or the whole report as JSON.
    #[arg(long, value_enum, default_value_t = ReportFormat::Table)]
    report: ReportFormat,
    /// Re-run the stages downstream of `--kind` on this recording (with the
    /// rig, plan and config it holds) instead of the simulated robot; the
    /// outputs go into OUT directly (`recording.mcap`, `report.json`, ...).
    #[arg(long, value_name = "FILE")]
    replay: Option<PathBuf>,
    /// With --replay: what to replay: `frames` re-runs the tracker and the
    /// mirror stage, `detections` the mirror stage.
    #[arg(long, value_enum, default_value_t = ReplayKind::Frames, requires = "replay")]
    kind: ReplayKind,
    /// Trace every stage step of every process into
    /// `OUT/mirror<i>/trace.json` (Chrome trace format; open it in Perfetto).
    #[arg(long)]
    trace: bool,
    /// Run one side of a run split across two hosts (both sides from the
    /// same config): `robot` starts the camera, the arm driver, kinematics
    /// and (unless the config's `split.tracker` offloads it) the tracker;
    /// `workstation` the mirror stage and the recorder. A `bridge` on each
    /// side carries the topics between them (see docs/bridge.md).
    #[arg(long, value_enum, requires = "endpoint")]
    side: Option<Side>,
    /// With --side: zenoh endpoint to listen on (repeatable), e.g.
    /// `tcp/0.0.0.0:7447` (typically on the robot).
    #[arg(long, group = "endpoint", requires = "side")]
    listen: Vec<String>,
    /// With --side: zenoh endpoint of the other side (repeatable), e.g.
    /// `tcp/192.168.1.20:7447` (typically on the workstation).
    #[arg(long, group = "endpoint", requires = "side")]
    connect: Vec<String>,
    /// With --side: the bridge's key namespace; both sides give the same,
    /// a second robot on the same network another.
    #[arg(long, default_value = split::DEFAULT_NAMESPACE, requires = "side")]
    namespace: String,
}

/// What `--replay` publishes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ReplayKind {
    /// Frames and joint states: the tracker and the mirror stage re-run.
    Frames,
    /// Detections and joint states: the mirror stage re-runs.
    Detections,
}

impl ReplayKind {
    fn kind(self) -> recorder::replay::Kind {
        match self {
            ReplayKind::Frames => recorder::replay::Kind::Frames,
            ReplayKind::Detections => recorder::replay::Kind::Detections,
        }
    }
}

/// The form of the final report on stdout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ReportFormat {
    /// The paper's table and the latency table.
    Table,
    /// The full report (the same as OUT/report.json).
    Json,
}

fn run(args: Args) -> Result<()> {
    if args.no_record && args.live_view.is_some() {
        bail!("--live-view is served by the recorder: it cannot be used with --no-record");
    }
    if args.side == Some(Side::Robot) && (args.live_view.is_some() || args.no_record) {
        bail!(
            "--live-view and --no-record are the recorder's, which runs on the workstation side: \
             give them there"
        );
    }
    if args.side.is_some() && args.replay.is_some() {
        bail!("--side cannot be used with --replay: a replay runs on one host");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create", args.out.display()))?;
    let replay = match &args.replay {
        Some(file) => {
            for (given, flag) in [
                (args.mirrors.is_some(), "--mirrors"),
                (args.poses.is_some(), "--poses"),
                (args.fps.is_some(), "--fps"),
                (args.arm_driver.is_some(), "--arm-driver"),
            ] {
                if given {
                    bail!("{flag} cannot be used with --replay: the recording fixes it");
                }
            }
            Some((file.clone(), replay::unpack(file, &args.out)?))
        }
        None => None,
    };
    let overrides = Overrides {
        mirrors: args.mirrors,
        train_poses: args.poses,
        method: args.method,
        fps: args.fps,
        arm_driver: args.arm_driver,
        realtime_priority: args.realtime_priority,
    };
    let config_path = replay
        .as_ref()
        .map_or(args.config.clone(), |(_, r)| r.config.clone());
    let config = Config::load(&config_path, overrides)?;
    let bin_dir = std::env::current_exe()?
        .parent()
        .context("no executable directory")?
        .to_path_buf();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst))
        .context("installing the Ctrl-C handler")?;
    // A replay paces itself: only a live run's stages race the clock.
    let realtime = match replay {
        Some(_) => None,
        None => scheduling::realtime(config.realtime_priority),
    };
    let run = Run {
        config,
        realtime,
        config_path,
        out: args.out.clone(),
        bin_dir,
        prefix: args
            .prefix
            .unwrap_or_else(|| format!("run{}", std::process::id())),
        record: !args.no_record,
        live_view: args.live_view,
        trace: args.trace,
        link: args.side.map(|side| Link {
            side,
            listen: args.listen,
            connect: args.connect,
            namespace: args.namespace,
        }),
        stop,
    };
    let results = match &replay {
        Some((file, unpacked)) => vec![run.replay(file, args.kind.kind(), unpacked.mirror)?],
        None => run
            .config
            .mirrors
            .iter()
            .map(|&m| run.placement(m))
            .collect::<Result<Vec<_>>>()?,
    };
    let path = args.out.join("report.json");
    let json = serde_json::json!({
        "config": run.config,
        "realtime_priority": run.realtime,
        "paper": PAPER_FIGURES,
        "placements": results,
    });
    let text = serde_json::to_string_pretty(&json)? + "\n";
    std::fs::write(&path, &text).with_context(|| format!("{}: cannot write", path.display()))?;
    if args.report == ReportFormat::Json {
        print!("{text}");
    } else {
        if args.side != Some(Side::Robot) {
            print!("{}", report::table(&results, run.config.method));
        }
        print!("{}", report::latency_table(&results));
        print!("{}", report::cpu_table(&results));
        if replay.is_some() {
            println!(
                "report: {}  (in {}: recording.mcap, mirror_report.json, rig.toml, plan.csv, \
                 stages.log, journal.mcap; compare with `replay diff`)",
                path.display(),
                args.out.display()
            );
        } else {
            println!(
                "report: {}  (per placement: {}/mirror<i>/{{report.json, recording.mcap, rig.toml, \
                 plan.csv, stages.log, journal.mcap, arm_journal.mcap}})",
                path.display(),
                args.out.display()
            );
        }
    }
    // A run that ends without a calibration failed, whatever else it did.
    let uncalibrated: Vec<String> = results
        .iter()
        .filter_map(|r| Some((r.mirror, r.report.as_ref()?)))
        .filter(|(_, report)| report.calibration.is_none())
        .map(|(mirror, report)| {
            format!(
                "mirror {mirror}: no calibration: {}",
                report.last_error.as_deref().unwrap_or("no reason given")
            )
        })
        .collect();
    if !uncalibrated.is_empty() {
        bail!("{}", uncalibrated.join("; "));
    }
    Ok(())
}

fn main() -> ExitCode {
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pipeline: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
