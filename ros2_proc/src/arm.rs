//! The arm driver of a ROS 2 robot: its `/joint_states` become our
//! `joint_positions` (by joint name, in our order, in our units and on our
//! clock), and each pose goal becomes a one-point `JointTrajectory` for its
//! trajectory controller. `kinematics_proc` decides when the arm has
//! settled, as with any driver.

use std::collections::{BTreeMap, BTreeSet};
use std::ops::ControlFlow;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use geometry::JointKind;
use messages::{JointPositions, MAX_JOINTS, PoseGoal, now_ns, topics};
use runtime::BusError;
use runtime::stats::StageStats;
use stages::ros2::Ros2Arm;

use crate::clock;
use crate::msgs::{self, Header, JointState, JointTrajectory, JointTrajectoryPoint};
use crate::node::{Node, Refusal, Ros2Error, RosSubscriber};
use crate::wire::Qos;

/// What stops the arm driver.
#[derive(Debug, thiserror::Error)]
pub enum ArmError {
    /// The pipeline's bus.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The graph.
    #[error(transparent)]
    Ros2(#[from] Ros2Error),
    /// The robot's joint states stopped (or never came).
    #[error("no {topic} from {endpoint} for {silent_ms} ms{hint}")]
    Silent {
        /// The topic.
        topic: String,
        /// The graph's endpoint.
        endpoint: String,
        /// How long.
        silent_ms: u128,
        /// What to check, if none ever came.
        hint: &'static str,
    },
    /// The joint states come from a graph we cannot speak to.
    #[error(transparent)]
    Unsupported(Refusal),
    /// The arm has more joints than a message holds.
    #[error("the arm has {0} joints; at most {MAX_JOINTS} are supported")]
    TooManyJoints(usize),
}

/// The arm and where its topics are.
#[derive(Debug, Clone)]
pub struct ArmOptions {
    /// The pipeline's prefix.
    pub prefix: String,
    /// Our joints, base to tip, by their names on the robot.
    pub joints: Vec<String>,
    /// Each joint's kind (prismatic joints are m in ROS, mm here).
    pub kinds: Vec<JointKind>,
    /// The joint-state topic.
    pub joint_states: String,
    /// The trajectory controller's topic.
    pub trajectory: String,
    /// `time_from_start` of each goal, ns.
    pub move_ns: i64,
    /// How long the joint states may be silent.
    pub silent: Duration,
}

/// ROS units (rad, m) per ours (rad, mm).
fn ros_per_ours(kind: JointKind) -> f64 {
    match kind {
        JointKind::Revolute => 1.0,
        JointKind::Prismatic => 1e-3,
    }
}

/// A ROS stamp further than this from our receive time is taken for a
/// clock that is not synchronised, and replaced by the receive time.
const MAX_STAMP_SKEW_NS: i64 = 1_000_000_000;

/// Runs until the plan is finished (a goal flagged finished), the joint
/// states go silent, or SIGINT/SIGTERM.
pub fn run(node: &Node, options: &ArmOptions) -> Result<(), ArmError> {
    let dof = options.joints.len();
    if dof > MAX_JOINTS {
        return Err(ArmError::TooManyJoints(dof));
    }
    let states = node.subscriber::<JointState>(&options.joint_states, Qos::reliable(10), 64)?;
    let trajectories = node.publisher::<JointTrajectory>(&options.trajectory, Qos::reliable(10))?;
    let stop = Arc::new(AtomicBool::new(false));
    let reader = {
        let stop = stop.clone();
        let options = options.clone();
        let endpoint = node.endpoint().to_string();
        std::thread::Builder::new()
            .name("joint_states".into())
            .spawn(move || read_joint_states(states, &options, &endpoint, &stop))
            .expect("spawn the joint-state thread")
    };

    let bus = stages::bus_of::<Ros2Arm>(&options.prefix)?;
    let goals = bus.subscriber::<topics::PoseGoal>()?;
    let mut rejected = runtime::Rejections::default();
    let mut sent = 0u64;
    let mut last_sent: Option<(u64, [f64; MAX_JOINTS])> = None;
    let result = bus.wake()?.run(
        &[goals.listener()],
        Some(Duration::from_millis(50)),
        || -> Result<_, ArmError> {
            if stop.load(Ordering::Relaxed) {
                return Ok(ControlFlow::Break(()));
            }
            while let Some(goal) = goals.receive()? {
                match goal.fault(dof) {
                    Some(why) => rejected.reject("pose goal", goal.seq, &why),
                    None if goal.finished() => return Ok(ControlFlow::Break(())),
                    // The same goal again (kinematics_proc repeats the
                    // current one) is not sent again: a trajectory
                    // controller takes each new trajectory as starting now,
                    // so a repeat would stretch the move.
                    None if last_sent == Some((goal.pose, goal.q)) => {}
                    None => {
                        trajectories.publish(&trajectory_for(&goal, options))?;
                        last_sent = Some((goal.pose, goal.q));
                        sent += 1;
                    }
                }
            }
            Ok(ControlFlow::Continue(()))
        },
    );
    stop.store(true, Ordering::Relaxed);
    let read = reader
        .join()
        .expect("the joint-state thread does not panic");
    result?;
    let counts = read?;
    let mut stats = StageStats::new("ros2_arm");
    stats.count("trajectories_sent", sent);
    stats.count("pose_goals_rejected", rejected.count());
    for (name, n) in counts {
        stats.count(name, n);
    }
    stats.finish();
    tracing::info!(trajectories = sent, "stopped");
    Ok(())
}

/// The goal as a one-point trajectory, reached `move_ns` after it starts
/// (stamp zero: on receipt, as `joint_trajectory_controller` reads it).
pub fn trajectory_for(goal: &PoseGoal, options: &ArmOptions) -> JointTrajectory {
    JointTrajectory {
        header: Header::default(),
        joint_names: options.joints.clone(),
        points: vec![JointTrajectoryPoint {
            positions: goal
                .joints()
                .iter()
                .zip(&options.kinds)
                .map(|(q, kind)| q * ros_per_ours(*kind))
                .collect(),
            time_from_start: msgs::Duration::from_ns(options.move_ns),
            ..Default::default()
        }],
    }
}

/// Our joint positions (rad, mm) as a ROS joint state (rad, m) of `joints`,
/// stamped `wall_ns`.
pub fn joint_state_of(
    q: &[f64],
    joints: &[String],
    kinds: &[JointKind],
    wall_ns: i64,
) -> JointState {
    JointState {
        header: Header {
            stamp: msgs::Time::from_ns(wall_ns),
            frame_id: String::new(),
        },
        name: joints.to_vec(),
        position: q
            .iter()
            .zip(kinds)
            .map(|(v, kind)| v * ros_per_ours(*kind))
            .collect(),
        ..Default::default()
    }
}

/// Our joint positions from a joint state, or the first of our joints it
/// lacks.
pub fn positions_of<'a>(state: &JointState, options: &'a ArmOptions) -> Result<Vec<f64>, &'a str> {
    options
        .joints
        .iter()
        .zip(&options.kinds)
        .map(|(name, kind)| {
            state
                .name
                .iter()
                .position(|n| n == name)
                .and_then(|i| state.position.get(i))
                .map(|v| v / ros_per_ours(*kind))
                .ok_or(name.as_str())
        })
        .collect()
}

/// The reader thread: joint states in, joint positions out, until `stop`.
/// Returns its counters.
fn read_joint_states(
    states: RosSubscriber<JointState>,
    options: &ArmOptions,
    endpoint: &str,
    stop: &AtomicBool,
) -> Result<BTreeMap<&'static str, u64>, ArmError> {
    let result = forward_joint_states(&states, options, endpoint, stop);
    stop.store(true, Ordering::Relaxed);
    result
}

fn forward_joint_states(
    states: &RosSubscriber<JointState>,
    options: &ArmOptions,
    endpoint: &str,
    stop: &AtomicBool,
) -> Result<BTreeMap<&'static str, u64>, ArmError> {
    let bus = stages::bus_of::<Ros2Arm>(&options.prefix)?;
    let positions = bus.publisher::<topics::JointPositions>()?;
    let mut counts: BTreeMap<&'static str, u64> = [
        "joint_states",
        "joint_states_missing_joint",
        "joint_states_other_hash",
        "joint_states_malformed",
        "joint_states_restamped",
    ]
    .into_iter()
    .map(|k| (k, 0))
    .collect();
    let mut named: BTreeSet<String> = BTreeSet::new();
    let mut warn_once = |line: String| {
        if named.insert(line.clone()) {
            tracing::warn!("{line}");
        }
    };
    let dof = options.joints.len();
    let mut seq = 0u64;
    let mut last_heard: Option<Instant> = None;
    let started = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        let Some(received) = states.recv_timeout(Duration::from_millis(100)) else {
            let since = last_heard.unwrap_or(started).elapsed();
            if since > options.silent {
                return Err(ArmError::Silent {
                    topic: states.topic().to_string(),
                    endpoint: endpoint.to_string(),
                    silent_ms: since.as_millis(),
                    hint: if last_heard.is_none() {
                        ": is the robot's controller running on rmw_zenoh (RMW_IMPLEMENTATION=rmw_zenoh_cpp) in the same domain?"
                    } else {
                        ""
                    },
                });
            }
            continue;
        };
        let received_ns = now_ns();
        let state = match received {
            Ok(r) => r.message,
            Err(refusal @ Refusal::Humble { .. }) => return Err(ArmError::Unsupported(refusal)),
            Err(refusal @ Refusal::OtherHash { .. }) => {
                *counts.get_mut("joint_states_other_hash").expect("counter") += 1;
                warn_once(refusal.to_string());
                continue;
            }
            Err(refusal @ Refusal::Wire { .. }) => {
                let n = counts.get_mut("joint_states_malformed").expect("counter");
                *n += 1;
                if *n <= 10 || n.is_multiple_of(100) {
                    tracing::warn!(malformed = *n, "dropping a joint state: {refusal}");
                }
                continue;
            }
        };
        last_heard = Some(Instant::now());
        *counts.get_mut("joint_states").expect("counter") += 1;
        let q = match positions_of(&state, options) {
            Ok(q) => q,
            Err(missing) => {
                *counts
                    .get_mut("joint_states_missing_joint")
                    .expect("counter") += 1;
                warn_once(format!(
                    "{}: a joint state without joint {missing:?} (it names {:?}); such readings are counted and dropped",
                    states.topic(),
                    state.name
                ));
                continue;
            }
        };
        let stamp_ns = if state.header.stamp == msgs::Time::default() {
            received_ns
        } else {
            let mapped = clock::to_monotonic(state.header.stamp.ns());
            if (mapped - received_ns).abs() > MAX_STAMP_SKEW_NS {
                *counts.get_mut("joint_states_restamped").expect("counter") += 1;
                warn_once(format!(
                    "{}: joint-state stamps are more than 1 s from this host's clock; the receive time is used (synchronise the clocks)",
                    states.topic()
                ));
                received_ns
            } else {
                mapped
            }
        };
        let mut msg = JointPositions {
            seq,
            stamp_ns,
            dof: dof as u32,
            ..Default::default()
        };
        msg.q[..dof].copy_from_slice(&q);
        positions.send(msg)?;
        seq += 1;
    }
    Ok(counts)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options() -> ArmOptions {
        ArmOptions {
            prefix: "t".into(),
            joints: vec!["shoulder".into(), "slide".into()],
            kinds: vec![JointKind::Revolute, JointKind::Prismatic],
            joint_states: "/joint_states".into(),
            trajectory: "/t".into(),
            move_ns: 300_000_000,
            silent: Duration::from_secs(3),
        }
    }

    #[test]
    fn joints_are_taken_by_name_in_our_order_and_units() {
        let state = JointState {
            name: vec!["gripper".into(), "slide".into(), "shoulder".into()],
            position: vec![9.0, 0.25, 1.5],
            ..Default::default()
        };
        assert_eq!(positions_of(&state, &options()).unwrap(), vec![1.5, 250.0]);
        let lacking = JointState {
            name: vec!["shoulder".into()],
            position: vec![1.0],
            ..Default::default()
        };
        assert_eq!(positions_of(&lacking, &options()), Err("slide"));
        let goal = PoseGoal {
            dof: 2,
            q: {
                let mut q = [0.0; MAX_JOINTS];
                q[..2].copy_from_slice(&[0.5, 120.0]);
                q
            },
            ..Default::default()
        };
        let t = trajectory_for(&goal, &options());
        assert_eq!(t.joint_names, ["shoulder", "slide"]);
        assert_eq!(t.points[0].positions, [0.5, 0.12]);
        assert_eq!(
            t.points[0].time_from_start,
            msgs::Duration {
                sec: 0,
                nanosec: 300_000_000
            }
        );
    }
}
