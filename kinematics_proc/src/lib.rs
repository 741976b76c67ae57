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

use std::path::PathBuf;
use std::time::Duration;

pub use formats::plan::PlannedPose;
use geometry::{Arm, GeometryError, Role};
use messages::MAX_JOINTS;
use rand::{Rng, SeedableRng};
use runtime::BusError;
use runtime::journal::JournalError;

/// Why following the plan, or the simulated arm driver, stopped or could
/// not start.
#[derive(Debug, thiserror::Error)]
pub enum KinematicsError {
    /// The shared-memory bus failed (opening a port, receiving, sending).
    #[error(transparent)]
    Bus(#[from] BusError),
    /// Publishing a joint state failed.
    #[error("publishing joint states")]
    PublishStates(#[source] BusError),
    /// The journal of an earlier run could not be opened or read.
    #[error("resuming from the journal {}", path.display())]
    Resume {
        /// The journal.
        path: PathBuf,
        /// Why it could not be opened.
        #[source]
        source: JournalError,
    },
    /// A settled pose could not be journaled.
    #[error(transparent)]
    Journal(#[from] JournalError),
    /// The end-effector model failed on a reading's joint positions.
    #[error("forward kinematics")]
    ForwardKinematics(#[source] GeometryError),
    /// A peer the stage waits for before it starts (subscribers to the
    /// joint states, an arm driver) did not come.
    #[error("{what} did not appear within {} s", waited.as_secs())]
    NotAppeared {
        /// What was waited for.
        what: String,
        /// How long.
        waited: Duration,
    },
    /// The arm driver sent no usable joint positions for too long: it is
    /// gone, or everything it sends is refused.
    #[error(
        "the arm driver sent no usable joint positions for {:.1} s ({received} received, {rejected} rejected{})",
        silent_for.as_secs_f64(),
        last_because(last_fault.as_deref())
    )]
    DriverSilent {
        /// How long nothing usable came.
        silent_for: Duration,
        /// Joint positions messages received in all.
        received: u64,
        /// Of those, how many were refused.
        rejected: u64,
        /// Why the last refused one was refused.
        last_fault: Option<String>,
    },
    /// An arm with more joints than the messages carry.
    #[error("the arm has {dof} joints; at most {MAX_JOINTS} are supported")]
    TooManyJoints {
        /// The arm's joints.
        dof: usize,
    },
}

/// The end of [`KinematicsError::DriverSilent`]'s message: why the last
/// refused reading was refused, if one was.
fn last_because(fault: Option<&str>) -> String {
    fault
        .map(|why| format!(", the last because: {why}"))
        .unwrap_or_default()
}

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
