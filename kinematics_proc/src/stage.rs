//! The stage's loop: the joint state of each tick, stamped and published.

use std::ops::ControlFlow;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use geometry::{Arm, Role};
use messages::journal::Journal;
use messages::topics::{self, Topic};
use messages::{Bus, JointState, Phase, now_ns};

use crate::{Motion, PlannedPose};

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

/// Where a restarted driver takes up its plan: after the last pose its
/// journal says the arm reached (settled at), starting from that pose's
/// joint angles; `None` when it reached none.
pub fn resume_point(plan: &[PlannedPose], reached: &[JointState]) -> Option<(usize, Vec<f64>)> {
    let last = reached.last()?;
    let index = plan.iter().position(|p| p.pose == last.pose)?;
    Some((index + 1, last.joints().to_vec()))
}

/// Opens the driver's journal at `path` and, if an earlier run of it
/// reached some poses of `plan`, drops those from `plan` and starts from
/// the last one's joint angles instead of `home`.
pub fn resume(path: &Path, plan: &mut Vec<PlannedPose>, home: &mut Vec<f64>) -> Result<Journal> {
    let (journal, recovered) = Journal::open(path, &[topics::JointState::ID])
        .with_context(|| format!("resuming from the journal {}", path.display()))?;
    if let Some(why) = &recovered.dropped {
        tracing::warn!(
            "{}: dropped an incomplete record at its end ({why}); everything before it is kept",
            path.display()
        );
    }
    let reached: Vec<JointState> = recovered.messages::<topics::JointState>().collect();
    if let Some((next, q)) = resume_point(plan, &reached) {
        tracing::info!(
            reached = reached.len(),
            next_pose = plan.get(next).map(|p| p.pose),
            "resuming the pose plan from the journal {}",
            path.display()
        );
        plan.drain(..next);
        *home = q;
    }
    Ok(journal)
}

/// Publishes `motion`'s joint states on pipeline `prefix` every `tick`,
/// once `wait_subscribers` listen (at most 30 s), until the plan is done;
/// returns how many it published. With `journal`, each pose the arm
/// reaches is journaled when it settles there.
pub fn drive(
    prefix: &str,
    arm: &Arm,
    motion: &Motion,
    tick: Duration,
    wait_subscribers: usize,
    mut journal: Option<Journal>,
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
    let mut reached = None::<u64>;
    bus.wake()?.run(&[], Some(tick), || -> Result<_> {
        let stamp = now_ns();
        let msg = joint_state(motion, arm, seq, stamp, stamp - start)?;
        seq += 1;
        let _span = tracing::trace_span!("kinematics_step", seq).entered();
        // Journaled before it is published: a restart never repeats a pose
        // the arm was seen holding.
        if msg.phase == Phase::Settled as u32
            && reached != Some(msg.pose)
            && let Some(journal) = &mut journal
        {
            journal.append::<topics::JointState>(&msg)?;
            reached = Some(msg.pose);
        }
        publisher.send(msg).context("publishing joint states")?;
        Ok(if msg.phase == Phase::Done as u32 {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        })
    })?;
    Ok(seq)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_restart_takes_up_the_plan_after_the_last_pose_reached() {
        let plan: Vec<PlannedPose> = (10..14)
            .map(|pose| PlannedPose {
                pose,
                role: Role::Train,
                q: vec![pose as f64; 2],
            })
            .collect();
        assert_eq!(resume_point(&plan, &[]), None);
        let reached = |pose: u64| {
            let mut js = JointState {
                pose,
                dof: 2,
                ..Default::default()
            };
            js.q[..2].copy_from_slice(&[pose as f64; 2]);
            js
        };
        assert_eq!(
            resume_point(&plan, &[reached(10), reached(11)]),
            Some((2, vec![11.0, 11.0]))
        );
        assert_eq!(
            resume_point(&plan, &[reached(13)]),
            Some((4, vec![13.0, 13.0]))
        );
    }
}
