//! `ros2_proc`: the pipeline's stages on a ROS 2 graph over rmw_zenoh.

use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use ros2_proc::arm::{self, ArmOptions};
use ros2_proc::node::{Node, NodeOptions};
use ros2_proc::tf::{self, TfOptions};

/// Join a ROS 2 graph that runs on rmw_zenoh (Jazzy or later) with no ROS
/// installed.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Be the arm driver of a ROS 2 robot: its joint states in, each pose
    /// goal out as a JointTrajectory.
    Arm(stages::ros2::ArmArgs),
    /// Publish each calibration on /tf_static (latched) and each located
    /// object as a PointStamped.
    Tf(stages::ros2::TfArgs),
}

/// Joins the graph as node `name`.
fn join(graph: &stages::ros2::Graph, name: &str) -> Result<Node> {
    Ok(Node::open(&NodeOptions {
        endpoint: graph.endpoint.clone(),
        domain: graph.domain,
        namespace: graph.namespace.clone(),
        name: name.into(),
    })?)
}

fn arm(args: stages::ros2::ArmArgs) -> Result<()> {
    let rig = formats::rig::read(&args.rig)?;
    let Some(robot_arm) = rig.arm else {
        bail!("{}: the rig has no [arm]", args.rig.display())
    };
    let node = join(&args.graph, "mirror_arm")?;
    arm::run(
        &node,
        &ArmOptions {
            prefix: args.prefix,
            joints: robot_arm.joint_names(),
            kinds: robot_arm.joint_kinds(),
            joint_states: args.joint_states,
            trajectory: args.trajectory,
            move_ns: i64::try_from(args.move_ms)
                .ok()
                .and_then(|ms| ms.checked_mul(1_000_000))
                .context("--move-ms is too large")?,
            silent: Duration::from_millis(args.silent_ms),
        },
    )?;
    Ok(())
}

fn tf(args: stages::ros2::TfArgs) -> Result<()> {
    let rig = formats::rig::read(&args.rig)?;
    let node = join(&args.graph, "mirror_calibration")?;
    tf::run(
        &node,
        &rig,
        &TfOptions {
            prefix: args.prefix,
            tf_static: args.tf_static,
            located: args.located,
        },
    )?;
    Ok(())
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::stage_main("ros2_proc", || match args.command {
        Command::Arm(a) => arm(a),
        Command::Tf(a) => tf(a),
    })
}
