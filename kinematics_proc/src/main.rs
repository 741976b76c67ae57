//! `kinematics_proc`: owns the pose plan. It sends each pose goal to the
//! arm driver, follows the driver's joint positions until the arm has
//! settled and held the pose, and publishes joint states with the
//! end-effector model's position.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Result, bail};
use clap::Parser;
use kinematics_proc::follow::SettleRule;
use kinematics_proc::random_plan;
use kinematics_proc::stage::DriveOptions;

/// Run a pose plan through the arm driver and publish the arm's joint states.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    prefix: String,
    /// Rig file (TOML) with the arm's model (DH table or URDF).
    #[arg(long)]
    rig: PathBuf,
    /// Pose plan CSV (`pose,role,q0..`); or use --random.
    #[arg(long, conflicts_with = "random")]
    plan: Option<PathBuf>,
    /// Random training poses within the joint limits, instead of a plan.
    #[arg(long)]
    random: Option<usize>,
    /// Seed of --random.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Hold each settled pose this long before the next goal, ms.
    #[arg(long, default_value_t = 300)]
    dwell_ms: u64,
    /// A pose has settled when every joint is within this of its goal (rad, or mm for a
    /// prismatic joint)...
    #[arg(long, default_value_t = 2e-3)]
    settle_tolerance: f64,
    /// ...and has stayed within half of it for this long, ms.
    #[arg(long, default_value_t = 40)]
    still_ms: u64,
    /// Fail when the arm driver sends no usable joint positions for this long, ms.
    #[arg(long, default_value_t = 3000)]
    silent_ms: u64,
    /// Wait until this many subscribers listen to the joint states (at most 30 s).
    #[arg(long, default_value_t = 0)]
    wait_subscribers: usize,
    /// Journal each pose the arm settles at here (MCAP); if the file exists,
    /// take up the plan after the last pose it holds (a restarted stage
    /// repeats no pose). Give a new path for a new run.
    #[arg(long)]
    journal: Option<PathBuf>,
}

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
    messages::stage_main("kinematics_proc", || run(Args::parse()))
}
