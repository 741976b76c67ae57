//! `kinematics_proc`: owns the pose plan. It sends each pose goal to the
//! arm driver, follows the driver's joint positions until the arm has
//! settled and held the pose, and publishes joint states with the
//! end-effector model's position.

use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Result, bail};
use clap::Parser;
use kinematics_proc::follow::SettleRule;
use kinematics_proc::random_plan;
use kinematics_proc::stage::DriveOptions;
use stages::kinematics::Args;

fn run(args: Args) -> Result<()> {
    let rig = formats::rig::read(&args.rig)?;
    let Some(arm) = rig.arm.clone() else {
        bail!("{}: the rig has no [arm]", args.rig.display())
    };
    if !(args.settle_tolerance > 0.0 && args.settle_tolerance.is_finite()) {
        bail!("--settle-tolerance must be positive");
    }
    let mut plan = match (&args.plan, args.random) {
        (Some(path), _) => formats::plan::read(path, arm.dof())?,
        (None, Some(n)) => random_plan(&arm, n, args.seed),
        (None, None) => bail!("give --plan FILE or --random N"),
    };
    let journal = args
        .journal
        .as_deref()
        .map(|path| kinematics_proc::stage::resume(path, &mut plan))
        .transpose()?;
    let options = DriveOptions {
        settle: SettleRule {
            tolerance: args.settle_tolerance,
            still_ns: (args.still_ms * 1_000_000) as i64,
            dwell_ns: (args.dwell_ms * 1_000_000) as i64,
        },
        wait_subscribers: args.wait_subscribers,
        silent_after: Duration::from_millis(args.silent_ms),
        ..DriveOptions::default()
    };
    let states = kinematics_proc::stage::drive(&args.prefix, &arm, plan, options, journal)?;
    tracing::info!(states, "pose plan done");
    Ok(())
}

fn main() -> ExitCode {
    runtime::stage_main("kinematics_proc", || run(Args::parse()))
}
