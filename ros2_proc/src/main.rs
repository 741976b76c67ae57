//! `ros2_proc`: the pipeline's stages on a ROS 2 graph over rmw_zenoh.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use ros2_proc::arm::{self, ArmOptions};
use ros2_proc::camera::{self, CameraOptions};
use ros2_proc::msgs::CameraInfo;
use ros2_proc::node::{Node, NodeOptions};
use ros2_proc::tf::{self, TfOptions};
use ros2_proc::wire::Qos;

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
    /// Be the stereo camera: pair two sensor_msgs/Image topics by stamp
    /// and publish each pair as a frame.
    Camera(stages::ros2::CameraArgs),
    /// Write a camera's CameraInfo as the calibration file the rig's
    /// `calibration = FILE` reads (a ROS camera_info YAML), then exit.
    CameraInfo(CameraInfoArgs),
}

#[derive(Debug, clap::Args)]
struct CameraInfoArgs {
    /// The graph.
    #[command(flatten)]
    graph: stages::ros2::Graph,
    /// The CameraInfo topic (`/left/camera_info`).
    topic: String,
    /// The file to write.
    #[arg(long)]
    out: PathBuf,
    /// The camera's name in the file (default: the file's stem).
    #[arg(long)]
    name: Option<String>,
    /// How long to wait for a message, ms.
    #[arg(long, default_value_t = 5000)]
    wait_ms: u64,
}

/// Joins the graph as node `name`.
fn join(graph: &stages::ros2::Graph, name: &str) -> Result<Node> {
    Ok(Node::open(&NodeOptions {
        endpoint: graph.endpoint.clone(),
        domain: graph.domain,
        namespace: graph.namespace.clone(),
        name: name.into(),
        tls_ca: graph.tls_ca.clone(),
        tls_identity: graph.tls_cert.clone().zip(graph.tls_key.clone()),
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

fn camera(args: stages::ros2::CameraArgs) -> Result<()> {
    if !(args.tolerance_ms >= 0.0 && args.tolerance_ms <= 1000.0) {
        bail!(
            "--tolerance-ms must be in [0, 1000], not {}",
            args.tolerance_ms
        );
    }
    let node = join(&args.graph, "mirror_camera")?;
    camera::run(
        &node,
        &CameraOptions {
            prefix: args.prefix,
            left: args.left,
            right: args.right,
            tolerance_ns: (args.tolerance_ms * 1e6).round() as i64,
        },
    )?;
    Ok(())
}

fn camera_info(args: CameraInfoArgs) -> Result<()> {
    let node = join(&args.graph, "mirror_camera_info")?;
    let infos = node.subscriber::<CameraInfo>(&args.topic, Qos::reliable(10), 4)?;
    let wait = Duration::from_millis(args.wait_ms);
    let info = match infos.recv_timeout(wait) {
        Some(Ok(received)) => received.message,
        Some(Err(refusal)) => bail!("{refusal}"),
        None => bail!(
            "no CameraInfo on {} from {} within {} ms (is the camera driver running on rmw_zenoh in the same domain?)",
            infos.topic(),
            args.graph.endpoint,
            args.wait_ms
        ),
    };
    let name = args.name.unwrap_or_else(|| {
        args.out
            .file_stem()
            .map_or("camera".into(), |s| s.to_string_lossy().into_owned())
    });
    let yaml = camera::camera_info_yaml(&name, &info);
    // Checked as the rig will read it: a model or matrix we cannot use is
    // refused here, naming the topic, and no file is written.
    formats::camera_file::parse(&args.out, &yaml)
        .map_err(|e| anyhow::anyhow!("{}: {e}", infos.topic()))?;
    std::fs::write(&args.out, yaml)
        .with_context(|| format!("{}: cannot write", args.out.display()))?;
    println!(
        "{}: {}x{} {} from {}",
        args.out.display(),
        info.width,
        info.height,
        info.distortion_model,
        infos.topic()
    );
    Ok(())
}

fn main() -> ExitCode {
    let args = Args::parse();
    runtime::stage_main("ros2_proc", || match args.command {
        Command::Arm(a) => arm(a),
        Command::Tf(a) => tf(a),
        Command::Camera(a) => camera(a),
        Command::CameraInfo(a) => camera_info(a),
    })
}
