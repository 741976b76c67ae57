//! `kinematics_proc`: drives the arm through a pose plan and publishes joint
//! states with the end-effector model's position. For the simulated robot it
//! is the arm's driver; a real robot would read its encoders here.

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Parser;
use kinematics_proc::{Motion, Timing, random_plan};
use messages::topics::{self, Topic};
use messages::{Bus, JointState, MAX_JOINTS, Phase, Role, now_ns};

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
    let home: Vec<f64> = arm.joints.iter().map(|j| 0.5 * (j.min + j.max)).collect();
    let motion = Motion::new(
        plan,
        Timing {
            move_ms: args.move_ms,
            dwell_ms: args.dwell_ms,
        },
        home,
    );
    let bus = Bus::new(&args.prefix, "kinematics_proc")?;
    let publisher = bus.publisher::<topics::JointState>()?;
    let waited = Instant::now();
    while bus.subscriber_count(topics::JointState::ID)? < args.wait_subscribers {
        if waited.elapsed() > Duration::from_secs(30) {
            bail!(
                "{} subscribers on the joint states did not appear within 30 s",
                args.wait_subscribers
            );
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    tracing::info!(
        poses = motion.plan().len(),
        duration_s = motion.duration_ns() as f64 * 1e-9,
        "running the pose plan"
    );
    let start = now_ns();
    let mut seq = 0u64;
    bus.wake()?.run(
        &[],
        Some(Duration::from_secs_f64(1.0 / args.rate_hz)),
        || -> Result<_> {
            let stamp = now_ns();
            let state = motion.state_at(stamp - start);
            let planned = motion
                .plan()
                .get(state.index.min(motion.plan().len().saturating_sub(1)));
            let mut msg = JointState {
                seq,
                stamp_ns: stamp,
                pose: planned.map_or(0, |p| p.pose),
                phase: state.phase as u32,
                role: planned.map_or(Role::Train, |p| p.role) as u32,
                dof: state.q.len() as u32,
                ..JointState::default()
            };
            msg.q[..state.q.len()].copy_from_slice(&state.q);
            msg.model_point = arm
                .end_effector(&state.q, &[])
                .context("forward kinematics")?
                .into();
            seq += 1;
            let _span = tracing::trace_span!("kinematics_step", seq).entered();
            publisher.send(msg).context("publishing joint states")?;
            Ok(if state.phase == Phase::Done {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            })
        },
    )?;
    tracing::info!(states = seq, "pose plan done");
    Ok(())
}

fn main() -> ExitCode {
    messages::stage_main("kinematics_proc", || run(Args::parse()))
}
