//! `kinematics_proc`: drives the arm through a pose plan and publishes joint
//! states with the end-effector model's position. For the simulated robot it
//! is the arm's driver; a real robot would read its encoders here.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Result, bail};
use clap::Parser;
use kinematics_proc::{Motion, Timing, random_plan};
use messages::MAX_JOINTS;

/// Run a pose plan and publish the arm's joint states.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    prefix: String,
    /// Rig file (TOML) with the arm's DH model.
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
    /// Move time between poses, ms.
    #[arg(long, default_value_t = 300)]
    move_ms: u64,
    /// Dwell time at each pose, ms.
    #[arg(long, default_value_t = 300)]
    dwell_ms: u64,
    /// Joint-state publication rate, Hz.
    #[arg(long, default_value_t = 100.0)]
    rate_hz: f64,
    /// Wait until this many subscribers listen to the joint states (at most 30 s).
    #[arg(long, default_value_t = 0)]
    wait_subscribers: usize,
    /// Journal each pose the arm reaches here (MCAP); if the file exists,
    /// take up the plan after the last pose it holds (a restarted driver
    /// repeats no pose). Give a new path for a new run.
    #[arg(long)]
    journal: Option<PathBuf>,
}

fn run(args: Args) -> Result<()> {
    let rig = formats::rig::read(&args.rig)?;
    let Some(arm) = rig.arm.clone() else {
        bail!("{}: the rig has no [arm]", args.rig.display())
    };
    if arm.dof() > MAX_JOINTS {
        bail!(
            "{}: the arm has {} joints; at most {MAX_JOINTS} are supported",
            args.rig.display(),
            arm.dof()
        );
    }
    if !(args.rate_hz > 0.0 && args.rate_hz <= 1000.0) {
        bail!("--rate-hz must be in (0, 1000]");
    }
    let plan = match (&args.plan, args.random) {
        (Some(path), _) => formats::plan::read(path, arm.dof())?,
        (None, Some(n)) => random_plan(&arm, n, args.seed),
        (None, None) => bail!("give --plan FILE or --random N"),
    };
    let mut plan = plan;
    let mut home: Vec<f64> = arm
        .limits()
        .into_iter()
        .map(|(min, max)| 0.5 * (min + max))
        .collect();
    let journal = args
        .journal
        .as_deref()
        .map(|path| kinematics_proc::stage::resume(path, &mut plan, &mut home))
        .transpose()?;
    let motion = Motion::new(
        plan,
        Timing {
            move_ms: args.move_ms,
            dwell_ms: args.dwell_ms,
        },
        home,
    );
    let states = kinematics_proc::stage::drive(
        &args.prefix,
        &arm,
        &motion,
        Duration::from_secs_f64(1.0 / args.rate_hz),
        args.wait_subscribers,
        journal,
    )?;
    tracing::info!(states, "pose plan done");
    Ok(())
}

fn main() -> ExitCode {
    messages::stage_main("kinematics_proc", || run(Args::parse()))
}
