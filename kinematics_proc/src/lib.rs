//! The arm's driver: a pose plan and the motion through it.
//!
//! [`Motion::state_at`] is pure: given the time since the plan started it
//! says which pose the arm is moving to or holding and its joint angles
//! (a smooth-step move of `move_ms`, then a dwell of `dwell_ms`). The binary
//! only stamps and publishes what it returns.
//!
//! ```
//! use kinematics_proc::{Motion, PlannedPose, Timing};
//! let plan = vec![PlannedPose { pose: 0, role: 0, q: vec![0.0, 1.0] }];
//! let motion = Motion::new(plan, Timing { move_ms: 100, dwell_ms: 200 }, vec![0.0, 0.0]);
//! let s = motion.state_at(250_000_000);
//! assert_eq!(s.phase, messages::phase::SETTLED);
//! assert_eq!(s.q, vec![0.0, 1.0]);
//! ```
#![warn(missing_docs)]

use std::path::Path;

use anyhow::{Context, Result, bail};
use geometry::Arm;
use messages::{phase, role};
use rand::{Rng, SeedableRng};

/// One pose of the plan.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedPose {
    /// Pose id.
    pub pose: u64,
    /// [`messages::role`].
    pub role: u32,
    /// Joint angles (as the encoders will read them), rad.
    pub q: Vec<f64>,
}

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
    /// [`messages::phase`].
    pub phase: u32,
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
                phase: phase::DONE,
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
                phase: phase::SETTLED,
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
            phase: phase::MOVING,
            q,
        }
    }
}

/// Parses a role name.
pub fn parse_role(s: &str) -> Option<u32> {
    match s {
        "train" => Some(role::TRAIN),
        "test" => Some(role::TEST),
        "direct" => Some(role::DIRECT),
        _ => None,
    }
}

/// The name of a role.
pub fn role_name(r: u32) -> &'static str {
    match r {
        role::TRAIN => "train",
        role::TEST => "test",
        role::DIRECT => "direct",
        _ => "unknown",
    }
}

/// Reads a plan CSV: `pose,role,q0..qN-1` (`role` is train, test or direct).
pub fn read_plan(path: &Path, dof: usize) -> Result<Vec<PlannedPose>> {
    let shown = path.display().to_string();
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .with_context(|| format!("{shown}: cannot read"))?;
    let header = reader
        .headers()
        .with_context(|| format!("{shown}: line 1"))?
        .clone();
    let col = |name: &str| header.iter().position(|h| h == name);
    let pose_col =
        col("pose").with_context(|| format!("{shown}: line 1: missing column `pose`"))?;
    let role_col =
        col("role").with_context(|| format!("{shown}: line 1: missing column `role`"))?;
    let q_cols: Vec<usize> = (0..dof)
        .map(|i| {
            col(&format!("q{i}")).with_context(|| {
                format!("{shown}: line 1: missing column `q{i}` (the arm has {dof} joints)")
            })
        })
        .collect::<Result<_>>()?;
    let mut plan = Vec::new();
    for record in reader.records() {
        let record = record.with_context(|| format!("{shown}: bad row"))?;
        let line = record.position().map_or(0, |p| p.line());
        let cell = |c: usize| record.get(c).unwrap_or("");
        let pose = cell(pose_col)
            .parse()
            .with_context(|| format!("{shown}: line {line}: bad `pose`"))?;
        let Some(role) = parse_role(cell(role_col)) else {
            bail!(
                "{shown}: line {line}: `role` must be train, test or direct, not `{}`",
                cell(role_col)
            );
        };
        let q = q_cols
            .iter()
            .map(|&c| match cell(c).parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => bail!(
                    "{shown}: line {line}: `{}` is not a finite joint angle",
                    cell(c)
                ),
            })
            .collect::<Result<Vec<_>>>()?;
        plan.push(PlannedPose { pose, role, q });
    }
    Ok(plan)
}

/// Writes a plan CSV.
pub fn write_plan(path: &Path, plan: &[PlannedPose]) -> Result<()> {
    let dof = plan.first().map_or(0, |p| p.q.len());
    let mut text = String::from("pose,role");
    for i in 0..dof {
        text += &format!(",q{i}");
    }
    text += "\n";
    for p in plan {
        text += &format!("{},{}", p.pose, role_name(p.role));
        for q in &p.q {
            text += &format!(",{q}");
        }
        text += "\n";
    }
    std::fs::write(path, text).with_context(|| format!("{}: cannot write", path.display()))
}

/// `count` random training poses within the arm's joint limits (seeded).
pub fn random_plan(arm: &Arm, count: usize, seed: u64) -> Vec<PlannedPose> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..count as u64)
        .map(|pose| PlannedPose {
            pose,
            role: role::TRAIN,
            q: arm
                .joints
                .iter()
                .map(|j| rng.random_range(j.min..=j.max))
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
                role: role::TRAIN,
                q: vec![1.0, -1.0],
            },
            PlannedPose {
                pose: 8,
                role: role::TEST,
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
        assert_eq!((s.index, s.phase), (0, phase::MOVING));
        assert!(
            (s.q[0] - 0.5).abs() < 1e-12,
            "half way in time is half way in angle"
        );
        assert_eq!(m.state_at(100_000_000).phase, phase::SETTLED);
        assert_eq!(m.state_at(399_999_999).q, vec![1.0, -1.0]);
        let s = m.state_at(400_000_001);
        assert_eq!((s.index, s.phase), (1, phase::MOVING));
        assert!((s.q[0] - 1.0).abs() < 1e-6);
        assert_eq!(m.state_at(800_000_000).phase, phase::DONE);
        assert_eq!(m.duration_ns(), 800_000_000);
    }

    #[test]
    fn plan_files_round_trip_and_bad_rows_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("plan.csv");
        write_plan(&path, motion().plan()).unwrap();
        assert_eq!(read_plan(&path, 2).unwrap(), motion().plan());
        let e = read_plan(&path, 3).unwrap_err().to_string();
        assert!(e.contains("plan.csv: line 1: missing column `q2`"), "{e}");
        std::fs::write(&path, "pose,role,q0\n1,train,NaN\n").unwrap();
        let e = read_plan(&path, 1).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("NaN"), "{e}");
    }
}
