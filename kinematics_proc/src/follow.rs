//! Following a pose plan from the arm driver's joint positions: which goal
//! to send, when the arm has settled at it, and the joint state to publish.
//! Pure: time comes from the positions' stamps.

use std::collections::VecDeque;

use geometry::Arm;
use messages::{JointPositions, JointState, MAX_JOINTS, Phase, PoseGoal};

use crate::{KinematicsError, PlannedPose};

/// When a pose counts as settled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SettleRule {
    /// Largest distance from the goal, per joint, in the joints' units (rad, mm).
    pub tolerance: f64,
    /// How long the positions must stay within half the tolerance of each other, ns.
    pub still_ns: i64,
    /// How long the arm holds a settled pose before the next goal, ns.
    pub dwell_ns: i64,
}

impl Default for SettleRule {
    fn default() -> Self {
        Self {
            tolerance: 2e-3,
            still_ns: 40_000_000,
            dwell_ns: 300_000_000,
        }
    }
}

/// What one reading led to.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// The joint state to publish.
    pub state: JointState,
    /// The arm has just settled at its goal, this long after the goal was sent, ns.
    pub settled_after_ns: Option<i64>,
    /// A new goal to send (the next pose, or the end of the plan).
    pub goal: Option<PoseGoal>,
}

/// The plan's progress.
#[derive(Debug, Clone)]
pub struct Follower {
    plan: Vec<PlannedPose>,
    rule: SettleRule,
    index: usize,
    phase: Phase,
    settled_at: i64,
    goal_sent_ns: i64,
    recent: VecDeque<(i64, [f64; MAX_JOINTS])>,
    state_seq: u64,
    goal_seq: u64,
}

impl Follower {
    /// Follows `plan` by `rule`.
    pub fn new(plan: Vec<PlannedPose>, rule: SettleRule) -> Self {
        Self {
            plan,
            rule,
            index: 0,
            phase: Phase::Moving,
            settled_at: 0,
            goal_sent_ns: 0,
            recent: VecDeque::new(),
            state_seq: 0,
            goal_seq: 0,
        }
    }

    /// Whether every pose has been held.
    pub fn done(&self) -> bool {
        self.index >= self.plan.len()
    }

    /// The goal to send now, stamped `now_ns`: the current pose, or the end
    /// of the plan. Sending it again is harmless.
    pub fn goal(&mut self, now_ns: i64) -> PoseGoal {
        let mut goal = PoseGoal {
            seq: self.goal_seq,
            stamp_ns: now_ns,
            ..PoseGoal::default()
        };
        self.goal_seq += 1;
        match self.plan.get(self.index) {
            Some(p) => {
                goal.pose = p.pose;
                goal.role = p.role as u32;
                goal.dof = p.q.len() as u32;
                goal.q[..p.q.len()].copy_from_slice(&p.q);
            }
            None => goal.flags = PoseGoal::FINISHED,
        }
        goal
    }

    /// Marks the current goal as sent at `now_ns` (the start of its move).
    pub fn sent(&mut self, now_ns: i64) {
        self.goal_sent_ns = now_ns;
    }

    fn still(&self, stamp: i64, q: &[f64]) -> bool {
        let covered = self
            .recent
            .front()
            .is_some_and(|(t, _)| stamp - t >= self.rule.still_ns);
        covered
            && self.recent.iter().all(|(_, r)| {
                r.iter()
                    .zip(q)
                    .all(|(a, b)| (a - b).abs() <= 0.5 * self.rule.tolerance)
            })
    }

    /// Takes one validated reading of `arm`'s joints; fails only when the
    /// end-effector model does ([`KinematicsError::ForwardKinematics`]).
    pub fn step(&mut self, p: &JointPositions, arm: &Arm) -> Result<Step, KinematicsError> {
        let q = p.joints();
        // Keep just enough history to judge stillness over the window.
        self.recent.push_back((p.stamp_ns, p.q));
        while self
            .recent
            .get(1)
            .is_some_and(|(t, _)| p.stamp_ns - t >= self.rule.still_ns)
        {
            self.recent.pop_front();
        }
        let mut settled_after_ns = None;
        let mut goal = None;
        let (pose, role, phase) = match self.plan.get(self.index) {
            None => (
                self.plan.last().map_or(0, |p| p.pose),
                self.plan.last().map_or(0, |p| p.role as u32),
                Phase::Done,
            ),
            Some(target) => {
                let near = target
                    .q
                    .iter()
                    .zip(q)
                    .all(|(g, v)| (g - v).abs() <= self.rule.tolerance);
                let (pose, role) = (target.pose, target.role as u32);
                let published = match self.phase {
                    Phase::Moving if near && self.still(p.stamp_ns, q) => {
                        self.phase = Phase::Settled;
                        self.settled_at = p.stamp_ns;
                        settled_after_ns = Some(p.stamp_ns - self.goal_sent_ns);
                        Phase::Settled
                    }
                    Phase::Settled if !near => {
                        self.phase = Phase::Moving;
                        Phase::Moving
                    }
                    Phase::Settled if p.stamp_ns - self.settled_at >= self.rule.dwell_ns => {
                        // This reading still shows the held pose (or the end
                        // of the plan); the next goal goes out.
                        self.index += 1;
                        self.phase = Phase::Moving;
                        goal = Some(self.goal(p.stamp_ns));
                        self.sent(p.stamp_ns);
                        if self.done() {
                            Phase::Done
                        } else {
                            Phase::Settled
                        }
                    }
                    current => current,
                };
                (pose, role, published)
            }
        };
        Ok(Step {
            state: self.state(p, arm, pose, role, phase)?,
            settled_after_ns,
            goal,
        })
    }

    fn state(
        &mut self,
        p: &JointPositions,
        arm: &Arm,
        pose: u64,
        role: u32,
        phase: Phase,
    ) -> Result<JointState, KinematicsError> {
        let q = p.joints();
        let mut state = JointState {
            seq: self.state_seq,
            stamp_ns: p.stamp_ns,
            pose,
            phase: phase as u32,
            role,
            dof: q.len() as u32,
            q: p.q,
            ..JointState::default()
        };
        self.state_seq += 1;
        state.model_point = arm
            .end_effector(q, &[])
            .map_err(KinematicsError::ForwardKinematics)?
            .into();
        Ok(state)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::Role;

    fn plan() -> Vec<PlannedPose> {
        vec![
            PlannedPose {
                pose: 7,
                role: Role::Train,
                q: vec![0.5, -0.2, 0.1, 0.3],
            },
            PlannedPose {
                pose: 8,
                role: Role::Direct,
                q: vec![1.0, 0.0, 0.0, 0.0],
            },
        ]
    }

    fn reading(t_ms: i64, q: [f64; 4]) -> JointPositions {
        let mut p = JointPositions {
            seq: t_ms as u64,
            stamp_ns: t_ms * 1_000_000,
            dof: 4,
            ..Default::default()
        };
        p.q[..4].copy_from_slice(&q);
        p
    }

    #[test]
    fn settles_when_near_and_still_holds_for_the_dwell_then_moves_on() {
        let arm = geometry::sim::nico_scene().rig.arm.unwrap();
        let rule = SettleRule {
            tolerance: 1e-3,
            still_ns: 40_000_000,
            dwell_ns: 100_000_000,
        };
        let mut f = Follower::new(plan(), rule);
        let first = f.goal(0);
        f.sent(0);
        assert_eq!((first.pose, first.dof, first.finished()), (7, 4, false));
        // Moving: far from the goal.
        let s = f.step(&reading(10, [0.2, 0.0, 0.0, 0.0]), &arm).unwrap();
        assert_eq!(s.state.phase, Phase::Moving as u32);
        // At the goal, but not yet still for 40 ms.
        let at = [0.5, -0.2, 0.1, 0.3];
        assert_eq!(
            f.step(&reading(50, at), &arm).unwrap().state.phase,
            Phase::Moving as u32
        );
        let s = f.step(&reading(90, at), &arm).unwrap();
        assert_eq!(s.state.phase, Phase::Settled as u32);
        assert_eq!(s.settled_after_ns, Some(90_000_000));
        assert_eq!(s.state.pose, 7);
        let model = arm.end_effector(&at, &[]).unwrap();
        assert_eq!(s.state.model_point, <[f64; 3]>::from(model));
        // Held for the dwell: the next goal goes out.
        assert!(f.step(&reading(150, at), &arm).unwrap().goal.is_none());
        let s = f.step(&reading(190, at), &arm).unwrap();
        let g = s.goal.unwrap();
        assert_eq!((g.pose, g.role), (8, Role::Direct as u32));
        assert_eq!(s.state.phase, Phase::Settled as u32);
        // The second pose; pulled away while settled, it is moving again.
        let there = [1.0, 0.0, 0.0, 0.0];
        f.step(&reading(200, there), &arm).unwrap();
        assert_eq!(
            f.step(&reading(250, there), &arm).unwrap().state.phase,
            Phase::Settled as u32
        );
        assert_eq!(
            f.step(&reading(260, [1.01, 0.0, 0.0, 0.0]), &arm)
                .unwrap()
                .state
                .phase,
            Phase::Moving as u32
        );
        f.step(&reading(300, there), &arm).unwrap();
        f.step(&reading(350, there), &arm).unwrap();
        let s = f.step(&reading(460, there), &arm).unwrap();
        assert!(s.goal.unwrap().finished());
        assert_eq!(s.state.phase, Phase::Done as u32);
        assert!(f.done());
        assert_eq!(
            f.step(&reading(470, there), &arm).unwrap().state.phase,
            Phase::Done as u32
        );
    }
}
