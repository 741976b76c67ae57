//! The arm: `kinematics_proc` owns the pose plan and turns the arm
//! driver's joint positions into joint states; `sim_arm` is the simulated
//! robot's driver. The contract between them is two topics:
//!
//! - `pose_goal` ([`messages::PoseGoal`]): `kinematics_proc` sends the pose
//!   to move to (and sends it again while the arm gets there); the last
//!   goal is flagged finished;
//! - `joint_positions` ([`messages::JointPositions`]): the driver publishes
//!   its encoders' readings, stamped, at its own rate.
//!
//! [`follow::Follower`] decides from the positions when a pose has settled
//! (near the goal and still) and when the dwell is over; it computes the
//! forward kinematics of each reading for the published
//! [`messages::JointState`]. Any process that speaks the two topics can
//! drive the arm: `python/mirror_driver` does it in Python.
//!
//! ```
//! use kinematics_proc::sim_arm::SimArm;
//! let mut arm = SimArm::new(vec![0.0, 0.0], 100_000_000);
//! arm.go_to(3, &[1.0, 0.5], 0);
//! assert_eq!(arm.at(100_000_000), vec![1.0, 0.5]);
//! ```

pub mod follow;
pub mod sim_arm;
pub mod stage;

pub use formats::plan::PlannedPose;
use geometry::{Arm, Role};
use rand::{Rng, SeedableRng};

/// The middle of each joint's range: where a simulated arm starts.
pub fn home(arm: &Arm) -> Vec<f64> {
    arm.limits()
        .into_iter()
        .map(|(min, max)| 0.5 * (min + max))
        .collect()
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
