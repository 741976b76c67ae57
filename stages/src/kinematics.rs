//! `kinematics_proc`: runs the pose plan through the arm driver and
//! publishes the arm's joint states.

use std::path::PathBuf;

use messages::topics::TopicId;
use runtime::Ports;
use serde::Serialize;

use crate::{FixedPorts, Home, RestartPolicy, Side, Stage};

/// Run a pose plan through the arm driver and publish the arm's joint states.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Parser)]
#[command(version, about)]
pub struct Args {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    pub prefix: String,
    /// Rig file (TOML) with the arm's model (DH table or URDF).
    #[arg(long)]
    pub rig: PathBuf,
    /// Pose plan CSV (`pose,role,q0..`); or use --random.
    #[arg(long, conflicts_with = "random")]
    pub plan: Option<PathBuf>,
    /// Random training poses within the joint limits, instead of a plan.
    #[arg(long)]
    pub random: Option<usize>,
    /// Seed of --random.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Hold each settled pose this long before the next goal, ms.
    #[arg(long, default_value_t = 300)]
    pub dwell_ms: u64,
    /// A pose has settled when every joint is within this of its goal (rad, or mm for a
    /// prismatic joint)...
    #[arg(long, default_value_t = 2e-3)]
    pub settle_tolerance: f64,
    /// ...and has stayed within half of it for this long, ms.
    #[arg(long, default_value_t = 40)]
    pub still_ms: u64,
    /// Fail when the arm driver sends no usable joint positions for this long, ms.
    #[arg(long, default_value_t = 3000)]
    pub silent_ms: u64,
    /// Wait until this many subscribers listen to the joint states (at most 30 s).
    #[arg(long, default_value_t = 0)]
    pub wait_subscribers: usize,
    /// Journal each pose the arm settles at here (MCAP); if the file exists,
    /// take up the plan after the last pose it holds (a restarted stage
    /// repeats no pose). Give a new path for a new run.
    #[arg(long)]
    pub journal: Option<PathBuf>,
}

impl Args {
    /// The arguments with their defaults, for `prefix` and `rig`.
    pub fn new(prefix: impl Into<String>, rig: impl Into<PathBuf>) -> Self {
        Self {
            prefix: prefix.into(),
            rig: rig.into(),
            plan: None,
            random: None,
            seed: 1,
            dwell_ms: 300,
            settle_tolerance: 2e-3,
            still_ms: 40,
            silent_ms: 3000,
            wait_subscribers: 0,
            journal: None,
        }
    }
}

/// The kinematics stage's declaration.
pub struct Kinematics;

impl FixedPorts for Kinematics {
    const PORTS: Ports<'static> = Ports {
        subscribes: &[TopicId::JointPositions],
        publishes: &[TopicId::JointState, TopicId::PoseGoal],
    };
}

impl Stage for Kinematics {
    type Args = Args;
    const BINARY: &'static str = "kinematics_proc";
    const HOME: Home = Home::On(Side::Robot);
    const SAMPLE_PATH_DEPTH: Option<u8> = Some(3);
    const RESTART: RestartPolicy = RestartPolicy::Finishes;

    fn ports(_: &Args) -> Ports<'_> {
        Self::PORTS
    }

    fn prefix(args: &Args) -> &str {
        &args.prefix
    }

    fn example() -> Args {
        Args {
            plan: Some("plan.csv".into()),
            dwell_ms: 150,
            wait_subscribers: 2,
            journal: Some("arm.mcap".into()),
            ..Args::new("p", "r.toml")
        }
    }
}
