//! `pipeline`: runs the whole live pipeline on the simulated robot, one
//! mirror placement after another, and prints the paper's table for the run.
//!
//! Per placement it writes `rig.toml` and `plan.csv` into `OUT/mirror<i>/`,
//! starts the stages from their declarations (the `stages` crate): `recorder` (unless
//! `--no-record`), `mirror_proc` and `tracker_proc`, then, each once every
//! stage before it is subscribed, `camera_proc` and the arm driver
//! (`sim_arm`, or `--arm-driver`), then `kinematics_proc` on the plan once
//! all are ([`supervise`]). A stage that
//! crashes is restarted as its policy says.
//! When the plan is done `mirror_proc` writes `report.json`; the launcher
//! stops the rest, evaluates the calibration against the simulator's truth
//! and writes `OUT/report.json` ([`report`]). Ctrl-C stops every stage
//! cleanly. With `--side robot|workstation` it runs one side of a run split
//! across two hosts, with a `bridge` to the other ([`split`]).

mod args;
mod certs;
mod combined;
mod config;
mod events;
mod replay;
mod report;
mod run;
mod scheduling;
mod split;
mod supervise;

use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use clap::Parser;

use crate::args::Args;
use crate::config::{Config, Overrides};
use crate::run::Run;
use crate::split::{Link, Side};

fn run(args: Args) -> Result<()> {
    if let Some(args::Task::Certs(certs)) = &args.command {
        return certs::run(certs);
    }
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
                (args.ros2.is_some(), "--ros2"),
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
        ros2: args.ros2,
        realtime_priority: args.realtime_priority,
        estimate: args.estimate,
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
    let link = args.side.map(|side| Link {
        side,
        listen: args.listen,
        connect: args.connect,
        namespace: args.namespace,
        certs: args.certs.or(config.split.certs.clone()),
        insecure: args.insecure,
    });
    if let Some(link) = &link {
        link.check()?;
    }
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
        live_view_bind: args.live_view_bind,
        trace: args.trace,
        link,
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
    // Across the placements, where this host ran the mirror stage.
    let estimate = run.config.estimate();
    let combined = if estimate.any() && args.side != Some(Side::Robot) {
        if replay.is_some() {
            bail!("--estimate cannot be used with --replay: a replay holds one placement");
        }
        if run.config.events.is_empty() {
            Some(combined::calibrate(&run, estimate))
        } else {
            // Its samples span the changes; each epoch is calibrated apart.
            eprintln!(
                "estimate: no combined calibration across the placements: the world changed during the run ([[event]]), and the combined calibration takes each placement's world to hold still"
            );
            None
        }
    } else {
        None
    };
    let (combined, failed) = match combined {
        Some(Ok(c)) => (Some(c), None),
        Some(Err(e)) => (None, Some(e)),
        None => (None, None),
    };
    report::finish(
        &results,
        combined.as_ref(),
        &run,
        &args.out,
        args.report,
        args.side,
        replay.is_some(),
    )?;
    // The placements' report is written first: a combined calibration
    // that cannot be made fails the run, but loses nothing.
    match failed {
        Some(e) => Err(e),
        None => Ok(()),
    }
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
