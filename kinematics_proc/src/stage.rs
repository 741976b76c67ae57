//! The stages' loops: `kinematics_proc` following its plan through the arm
//! driver, and the simulated arm driver.

use std::ops::ControlFlow;
use std::path::Path;
use std::time::{Duration, Instant};

use geometry::Arm;
use messages::topics::{self, Topic};
use messages::{JointPositions, JointState, MAX_JOINTS, Phase, now_ns};
use runtime::BusError;
use runtime::journal::Journal;

use crate::follow::{Follower, SettleRule};
use crate::sim_arm::SimArm;
use crate::{KinematicsError, PlannedPose};

/// Where a restarted `kinematics_proc` takes up its plan: the index after
/// the last pose its journal says the arm settled at; 0 when none.
pub fn resume_point(plan: &[PlannedPose], reached: &[JointState]) -> usize {
    reached
        .last()
        .and_then(|last| plan.iter().position(|p| p.pose == last.pose))
        .map_or(0, |i| i + 1)
}

/// Opens the journal at `path` and, if an earlier run reached some poses
/// of `plan`, drops those from `plan`. A journal that cannot be opened is a
/// [`KinematicsError::Resume`].
pub fn resume(path: &Path, plan: &mut Vec<PlannedPose>) -> Result<Journal, KinematicsError> {
    let (journal, recovered) =
        Journal::open(path, &[topics::JointState::ID]).map_err(|source| {
            KinematicsError::Resume {
                path: path.to_path_buf(),
                source,
            }
        })?;
    if let Some(why) = &recovered.dropped {
        tracing::warn!(
            "{}: dropped an incomplete record at its end ({why}); everything before it is kept",
            path.display()
        );
    }
    let reached: Vec<JointState> = recovered.messages::<topics::JointState>().collect();
    let next = resume_point(plan, &reached);
    if next > 0 {
        tracing::info!(
            reached = reached.len(),
            next_pose = plan.get(next).map(|p| p.pose),
            "resuming the pose plan from the journal {}",
            path.display()
        );
        plan.drain(..next);
    }
    Ok(journal)
}

/// How `kinematics_proc` runs the plan.
#[derive(Debug, Clone, Copy)]
pub struct DriveOptions {
    /// When a pose counts as settled, and the dwell.
    pub settle: SettleRule,
    /// Joint-state subscribers to wait for (at most 30 s) before the first goal.
    pub wait_subscribers: usize,
    /// Fail when the driver sends no usable positions for this long.
    pub silent_after: Duration,
    /// Send the current goal again this often until the arm settles.
    pub resend_every: Duration,
}

impl Default for DriveOptions {
    fn default() -> Self {
        Self {
            settle: SettleRule::default(),
            wait_subscribers: 0,
            silent_after: Duration::from_secs(3),
            resend_every: Duration::from_millis(250),
        }
    }
}

/// How long [`drive`] waits for its subscribers and for an arm driver.
const APPEAR_WITHIN: Duration = Duration::from_secs(30);

fn wait_for(
    what: &str,
    mut ready: impl FnMut() -> Result<bool, BusError>,
) -> Result<(), KinematicsError> {
    let waited = Instant::now();
    while !ready()? {
        if waited.elapsed() > APPEAR_WITHIN {
            return Err(KinematicsError::NotAppeared {
                what: what.to_string(),
                waited: APPEAR_WITHIN,
            });
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(())
}

/// Runs `plan` through the arm driver on pipeline `prefix`: sends each
/// pose goal, follows the driver's joint positions, publishes a joint
/// state for each, and journals each pose when the arm settles there.
/// Returns the joint states published. Fails when no arm driver comes
/// ([`KinematicsError::NotAppeared`]) or it goes silent
/// ([`KinematicsError::DriverSilent`]), and on the bus's or the journal's
/// failures.
pub fn drive(
    prefix: &str,
    arm: &Arm,
    plan: Vec<PlannedPose>,
    options: DriveOptions,
    mut journal: Option<Journal>,
) -> Result<u64, KinematicsError> {
    let bus = stages::bus_of::<stages::kinematics::Kinematics>(prefix)?;
    let states = bus.publisher::<topics::JointState>()?;
    let goals = bus.publisher::<topics::PoseGoal>()?;
    let positions = bus.subscriber::<topics::JointPositions>()?;
    wait_for(
        &format!(
            "{} subscribers on the joint states",
            options.wait_subscribers
        ),
        || Ok(bus.subscriber_count(topics::JointState::ID)? >= options.wait_subscribers),
    )?;
    wait_for("an arm driver subscribing to pose goals", || {
        Ok(bus.subscriber_count(topics::PoseGoal::ID)? >= 1)
    })?;
    let poses = plan.len();
    let mut follower = Follower::new(plan, options.settle);
    tracing::info!(poses, "running the pose plan");
    let dof = arm.dof();
    let mut stats = runtime::stats::StageStats::new("kinematics_proc");
    let mut rejections = runtime::Rejections::default();
    let mut order = runtime::StampOrder::default();
    let (mut published, mut received) = (0u64, 0u64);
    let mut last_fault = None::<String>;
    let mut last_heard = Instant::now();
    let mut last_sent = Instant::now();
    goals.send(follower.goal(now_ns()))?;
    follower.sent(now_ns());
    let silent_after = options.silent_after;
    bus.wake()?.run(
        &[positions.listener()],
        Some(Duration::from_millis(10)),
        || -> Result<_, KinematicsError> {
            while let Some(p) = positions.receive()? {
                received += 1;
                // Both reasons as text: the rejection log and the silent
                // driver's error name the last one.
                let checked = p.fault(dof).map_or_else(
                    || order.check(p.stamp_ns).map_err(|behind| behind.to_string()),
                    Err,
                );
                if let Err(why) = checked {
                    rejections.reject("joint positions message", p.seq, &why);
                    last_fault = Some(why);
                    continue;
                }
                last_heard = Instant::now();
                let _span = tracing::trace_span!("kinematics_step", seq = p.seq).entered();
                let cpu = runtime::stats::StepStart::now();
                let step = follower.step(&p, arm)?;
                if let Some(ns) = step.settled_after_ns {
                    stats.record("goal_to_settled", ns);
                    // Journaled before it is published: a restart never
                    // repeats a pose the arm was seen holding.
                    if let Some(journal) = &mut journal {
                        journal.append::<topics::JointState>(&step.state)?;
                    }
                }
                states
                    .send(step.state)
                    .map_err(KinematicsError::PublishStates)?;
                published += 1;
                stats.cpu_step(cpu);
                if let Some(goal) = step.goal {
                    goals.send(goal)?;
                    last_sent = Instant::now();
                }
                if step.state.phase == Phase::Done as u32 {
                    return Ok(ControlFlow::Break(()));
                }
            }
            if last_heard.elapsed() > silent_after {
                return Err(KinematicsError::DriverSilent {
                    silent_for: silent_after,
                    received,
                    rejected: rejections.count(),
                    last_fault: last_fault.take(),
                });
            }
            // A driver that started late, or restarted, gets the goal again.
            if last_sent.elapsed() > options.resend_every {
                goals.send(follower.goal(now_ns()))?;
                last_sent = Instant::now();
            }
            Ok(ControlFlow::Continue(()))
        },
    )?;
    stats.count("joint_positions", received);
    stats.count("joint_positions_rejected", rejections.count());
    stats.finish();
    Ok(published)
}

/// The simulated arm driver on pipeline `prefix`: publishes the joint
/// positions of an arm of `dof` joints starting at `home` every `tick`,
/// moving to each pose goal in `move_ns`, until a goal ends the plan.
/// An arm of more joints than the messages carry is a
/// [`KinematicsError::TooManyJoints`].
pub fn run_sim_arm(
    prefix: &str,
    home: Vec<f64>,
    move_ns: i64,
    tick: Duration,
) -> Result<(), KinematicsError> {
    let dof = home.len();
    if dof > MAX_JOINTS {
        return Err(KinematicsError::TooManyJoints { dof });
    }
    let bus = stages::bus_of::<stages::sim_arm::SimArm>(prefix)?;
    let positions = bus.publisher::<topics::JointPositions>()?;
    let goals = bus.subscriber::<topics::PoseGoal>()?;
    let mut arm = SimArm::new(home, move_ns);
    let mut rejections = runtime::Rejections::default();
    let mut stats = runtime::stats::StageStats::new("sim_arm");
    let mut seq = 0u64;
    bus.wake()?
        .run(&[], Some(tick), || -> Result<_, KinematicsError> {
            let cpu = runtime::stats::StepStart::now();
            let now = now_ns();
            let mut finished = false;
            while let Some(goal) = goals.receive()? {
                match goal.fault(dof) {
                    Some(why) => rejections.reject("pose goal", goal.seq, &why),
                    None if goal.finished() => finished = true,
                    None => arm.go_to(goal.pose, goal.joints(), now),
                }
            }
            let mut msg = JointPositions {
                seq,
                stamp_ns: now,
                dof: dof as u32,
                ..JointPositions::default()
            };
            msg.q[..dof].copy_from_slice(&arm.at(now));
            positions.send(msg)?;
            seq += 1;
            stats.cpu_step(cpu);
            Ok(if finished {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            })
        })?;
    stats.count("pose_goals_rejected", rejections.count());
    stats.finish();
    tracing::info!(positions = seq, "plan finished");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::Role;

    #[test]
    fn a_restart_takes_up_the_plan_after_the_last_pose_reached() {
        let plan: Vec<PlannedPose> = (10..14)
            .map(|pose| PlannedPose {
                pose,
                role: Role::Train,
                q: vec![pose as f64; 2],
            })
            .collect();
        assert_eq!(resume_point(&plan, &[]), 0);
        let reached = |pose: u64| JointState {
            pose,
            dof: 2,
            ..Default::default()
        };
        assert_eq!(resume_point(&plan, &[reached(10), reached(11)]), 2);
        assert_eq!(resume_point(&plan, &[reached(13)]), 4);
    }
}
