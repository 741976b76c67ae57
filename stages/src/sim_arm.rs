//! `sim_arm`: the simulated robot's arm driver.

use std::path::PathBuf;

use messages::topics::TopicId;
use runtime::Ports;
use serde::Serialize;

use crate::{FixedPorts, Home, RestartPolicy, Side, Stage};

/// The arm driver contract's ports: pose goals in, joint positions out.
/// Every arm driver (`sim_arm`, a user's) has these.
pub const DRIVER_PORTS: Ports<'static> = Ports {
    subscribes: &[TopicId::PoseGoal],
    publishes: &[TopicId::JointPositions],
};

/// Play the simulated arm: follow pose goals, publish joint positions.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Parser)]
#[command(version, about)]
pub struct Args {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    pub prefix: String,
    /// Rig file (TOML) with the arm: its joints and limits.
    #[arg(long)]
    pub rig: PathBuf,
    /// Time of each move, ms.
    #[arg(long, default_value_t = 300)]
    pub move_ms: u64,
    /// Joint-position publication rate, Hz (that of a typical arm
    /// controller's state stream).
    #[arg(long, default_value_t = 250.0)]
    pub rate_hz: f64,
}

/// The simulated arm driver's declaration.
pub struct SimArm;

impl FixedPorts for SimArm {
    const PORTS: Ports<'static> = DRIVER_PORTS;
}

impl Stage for SimArm {
    type Args = Args;
    const BINARY: &'static str = "sim_arm";
    const HOME: Home = Home::On(Side::Robot);
    const SAMPLE_PATH_DEPTH: Option<u8> = Some(5);
    const SOURCE: bool = true;
    /// It stops when the plan is finished, or is stopped with the run.
    const RESTART: RestartPolicy = RestartPolicy::Finishes;

    fn ports(_: &Args) -> Ports<'_> {
        Self::PORTS
    }

    fn prefix(args: &Args) -> &str {
        &args.prefix
    }

    fn example() -> Args {
        Args {
            prefix: "p".into(),
            rig: "r.toml".into(),
            move_ms: 120,
            rate_hz: 250.0,
        }
    }
}
