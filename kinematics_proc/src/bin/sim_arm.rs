//! `sim_arm`: the simulated robot's arm driver. It moves to each pose goal
//! in a fixed time and publishes its joint positions; the built-in arm
//! driver of `pipeline` (give `--arm-driver` for a real one).

use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Result, bail};
use clap::Parser;
use stages::sim_arm::Args;

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
    )?;
    Ok(())
}

fn main() -> ExitCode {
    runtime::stage_main("sim_arm", || run(Args::parse()))
}
