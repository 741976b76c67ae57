//! The stage's loop: the joint state of each tick, stamped and published.

use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use geometry::{Arm, Role};
use messages::topics::{self, Topic};
use messages::{Bus, JointState, Phase, now_ns};

use crate::Motion;

/// The joint state `since_start_ns` into `motion`, stamped `stamp_ns`, with
/// the arm model's end-effector position for its joint angles.
pub fn joint_state(
    motion: &Motion,
    arm: &Arm,
    seq: u64,
    stamp_ns: i64,
    since_start_ns: i64,
) -> Result<JointState> {
    let state = motion.state_at(since_start_ns);
    let plan = motion.plan();
    let planned = plan.get(state.index.min(plan.len().saturating_sub(1)));
    let mut msg = JointState {
        seq,
        stamp_ns,
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
    Ok(msg)
}

/// Publishes `motion`'s joint states on pipeline `prefix` every `tick`,
/// once `wait_subscribers` listen (at most 30 s), until the plan is done;
/// returns how many it published.
pub fn drive(
    prefix: &str,
    arm: &Arm,
    motion: &Motion,
    tick: Duration,
    wait_subscribers: usize,
) -> Result<u64> {
    let bus = Bus::new(prefix, "kinematics_proc")?;
    let publisher = bus.publisher::<topics::JointState>()?;
    let waited = Instant::now();
    while bus.subscriber_count(topics::JointState::ID)? < wait_subscribers {
        if waited.elapsed() > Duration::from_secs(30) {
            bail!("{wait_subscribers} subscribers on the joint states did not appear within 30 s");
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
    bus.wake()?.run(&[], Some(tick), || -> Result<_> {
        let stamp = now_ns();
        let msg = joint_state(motion, arm, seq, stamp, stamp - start)?;
        seq += 1;
        let _span = tracing::trace_span!("kinematics_step", seq).entered();
        publisher.send(msg).context("publishing joint states")?;
        Ok(if msg.phase == Phase::Done as u32 {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        })
    })?;
    Ok(seq)
}
