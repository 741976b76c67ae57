//! `sim_arm`: the simulated robot's arm driver. It moves to each pose goal
//! in a fixed time and publishes its joint positions; the built-in arm
//! driver of `pipeline` (give `--arm-driver` for a real one).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Result, bail};
use clap::Parser;

/// Play the simulated arm: follow pose goals, publish joint positions.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    prefix: String,
    /// Rig file (TOML) with the arm: its joints and limits.
    #[arg(long)]
    rig: PathBuf,
    /// Time of each move, ms.
    #[arg(long, default_value_t = 300)]
    move_ms: u64,
    /// Joint-position publication rate, Hz (that of a typical arm
    /// controller's state stream).
    #[arg(long, default_value_t = 250.0)]
    rate_hz: f64,
}

fn run(args: Args) -> Result<()> {
    let rig = formats::rig::read(&args.rig)?;
    let Some(arm) = rig.arm else {
        bail!("{}: the rig has no [arm]", args.rig.display())
    };
    if !(args.rate_hz > 0.0 && args.rate_hz <= 1000.0) {
        bail!("--rate-hz must be in (0, 1000]");
    }
    kinematics_proc::stage::run_sim_arm(
        &args.prefix,
        kinematics_proc::home(&arm),
        (args.move_ms * 1_000_000) as i64,
        Duration::from_secs_f64(1.0 / args.rate_hz),
    )
}

fn main() -> ExitCode {
    messages::stage_main("sim_arm", || run(Args::parse()))
}
