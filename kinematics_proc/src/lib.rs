//! The arm's driver: a pose plan and the motion through it.
//!
//! [`Motion::state_at`] is pure: given the time since the plan started it
//! says which pose the arm is moving to or holding and its joint angles
//! (a smooth-step move of `move_ms`, then a dwell of `dwell_ms`). The binary
//! only stamps and publishes what it returns.
//!
//! ```
//! use kinematics_proc::{Motion, PlannedPose, Timing};
//! use geometry::Role;
//! let plan = vec![PlannedPose { pose: 0, role: Role::Train, q: vec![0.0, 1.0] }];
//! let motion = Motion::new(plan, Timing { move_ms: 100, dwell_ms: 200 }, vec![0.0, 0.0]);
//! let s = motion.state_at(250_000_000);
//! assert_eq!(s.phase, messages::Phase::Settled);
//! assert_eq!(s.q, vec![0.0, 1.0]);
//! ```

pub mod stage;

pub use formats::plan::PlannedPose;
use geometry::{Arm, Role};
use messages::Phase;
use rand::{Rng, SeedableRng};

/// How long moves and dwells take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// Move between poses, ms.
    pub move_ms: u64,
    /// Hold at each pose, ms.
    pub dwell_ms: u64,
}

/// Where the arm is at some instant.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmState {
    /// Index into the plan (the pose moved to or held); the plan length once done.
    pub index: usize,
    /// What the arm is doing.
    pub phase: Phase,
    /// Joint angles, rad.
    pub q: Vec<f64>,
}

/// A plan and its timing.
#[derive(Debug, Clone)]
pub struct Motion {
    plan: Vec<PlannedPose>,
    timing: Timing,
    home: Vec<f64>,
}

impl Motion {
    /// Moves from `home` through `plan`.
    pub fn new(plan: Vec<PlannedPose>, timing: Timing, home: Vec<f64>) -> Self {
        Self { plan, timing, home }
    }

    /// The plan.
    pub fn plan(&self) -> &[PlannedPose] {
        &self.plan
    }

    /// Duration of the whole plan, ns.
    pub fn duration_ns(&self) -> i64 {
        self.plan.len() as i64 * self.period_ns()
    }

    fn period_ns(&self) -> i64 {
        ((self.timing.move_ms + self.timing.dwell_ms) * 1_000_000) as i64
    }

    /// The state `t_ns` after the start.
    pub fn state_at(&self, t_ns: i64) -> ArmState {
        let period = self.period_ns().max(1);
        let t = t_ns.max(0);
        let index = (t / period) as usize;
        if index >= self.plan.len() {
            let q = self.plan.last().map_or(self.home.clone(), |p| p.q.clone());
            return ArmState {
                index: self.plan.len(),
                phase: Phase::Done,
                q,
            };
        }
        let into = t - index as i64 * period;
        let move_ns = (self.timing.move_ms * 1_000_000) as i64;
        let from = if index == 0 {
            &self.home
        } else {
            &self.plan[index - 1].q
        };
        let to = &self.plan[index].q;
        if into >= move_ns {
            return ArmState {
                index,
                phase: Phase::Settled,
                q: to.clone(),
            };
        }
        let s = into as f64 / move_ns as f64;
        let smooth = s * s * (3.0 - 2.0 * s);
        let q = from
            .iter()
            .zip(to)
            .map(|(a, b)| a + (b - a) * smooth)
            .collect();
        ArmState {
            index,
            phase: Phase::Moving,
            q,
        }
    }
}

/// `count` random training poses within the arm's joint limits (seeded).
pub fn random_plan(arm: &Arm, count: usize, seed: u64) -> Vec<PlannedPose> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..count as u64)
        .map(|pose| PlannedPose {
            pose,
            role: Role::Train,
            q: arm
                .limits()
                .into_iter()
                .map(|(min, max)| rng.random_range(min..=max))
                .collect(),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn motion() -> Motion {
        let plan = vec![
            PlannedPose {
                pose: 7,
                role: Role::Train,
                q: vec![1.0, -1.0],
            },
            PlannedPose {
                pose: 8,
                role: Role::Test,
                q: vec![2.0, 0.0],
            },
        ];
        Motion::new(
            plan,
            Timing {
                move_ms: 100,
                dwell_ms: 300,
            },
            vec![0.0, 0.0],
        )
    }

    #[test]
    fn moves_smoothly_then_settles_then_finishes() {
        let m = motion();
        let s = m.state_at(50_000_000);
        assert_eq!((s.index, s.phase), (0, Phase::Moving));
        assert!(
            (s.q[0] - 0.5).abs() < 1e-12,
            "half way in time is half way in angle"
        );
        assert_eq!(m.state_at(100_000_000).phase, Phase::Settled);
        assert_eq!(m.state_at(399_999_999).q, vec![1.0, -1.0]);
        let s = m.state_at(400_000_001);
        assert_eq!((s.index, s.phase), (1, Phase::Moving));
        assert!((s.q[0] - 1.0).abs() < 1e-6);
        assert_eq!(m.state_at(800_000_000).phase, Phase::Done);
        assert_eq!(m.duration_ns(), 800_000_000);
    }
}
