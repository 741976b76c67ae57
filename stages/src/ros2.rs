//! `ros2_proc`: the pipeline's stages on a ROS 2 graph over rmw_zenoh.
//! `ros2_proc arm` is the arm driver of a ROS 2 robot: its `/joint_states`
//! in, `JointTrajectory` goals out. `ros2_proc tf` puts the calibration on
//! `/tf_static` and the located objects on a topic.

use std::path::PathBuf;
use std::time::Duration;

use messages::topics::TopicId;
use runtime::Ports;
use serde::Serialize;

use crate::sim_arm::DRIVER_PORTS;
use crate::{FixedPorts, Home, RestartPolicy, Side, Stage};

/// Where the ROS 2 graph is and who we are on it: what every `ros2_proc`
/// stage takes.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
pub struct Graph {
    /// Zenoh endpoint of the robot's router (`rmw_zenohd`) or a peer.
    #[arg(long, default_value = "tcp/localhost:7447")]
    pub endpoint: String,
    /// ROS domain id (the robot's `ROS_DOMAIN_ID`; `pipeline` passes its
    /// own environment's).
    #[arg(long, default_value_t = 0)]
    pub domain: u32,
    /// Namespace of our node (relative topic names are under it).
    #[arg(long, default_value = "/")]
    pub namespace: String,
    /// For a `tls/` endpoint: the CA certificate (PEM) the router's
    /// certificate must be signed by.
    #[arg(long, value_name = "FILE")]
    pub tls_ca: Option<PathBuf>,
    /// For a router that requires client certificates (mutual TLS): ours
    /// (PEM), signed by a CA the router trusts.
    #[arg(long, value_name = "FILE", requires_all = ["tls_ca", "tls_key"])]
    pub tls_cert: Option<PathBuf>,
    /// The private key of `--tls-cert` (PEM, readable by its owner only).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
}

impl Default for Graph {
    fn default() -> Self {
        Graph {
            endpoint: "tcp/localhost:7447".into(),
            domain: 0,
            namespace: "/".into(),
            tls_ca: None,
            tls_cert: None,
            tls_key: None,
        }
    }
}

/// Drive a ROS 2 arm: publish its `/joint_states` as joint positions and
/// send each pose goal as a `JointTrajectory`.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
pub struct ArmArgs {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    pub prefix: String,
    /// Rig file (TOML): the arm's joint names (its URDF's, or joint1..N).
    #[arg(long)]
    pub rig: PathBuf,
    /// The graph.
    #[command(flatten)]
    #[serde(flatten)]
    pub graph: Graph,
    /// Topic of the robot's joint states.
    #[arg(long, default_value = "/joint_states")]
    pub joint_states: String,
    /// Topic the trajectory controller takes trajectories on.
    #[arg(long, default_value = "/joint_trajectory_controller/joint_trajectory")]
    pub trajectory: String,
    /// `time_from_start` of each goal's trajectory point, ms.
    #[arg(long, default_value_t = 300)]
    pub move_ms: u64,
    /// Stop with an error when no joint state has come for this long, ms.
    #[arg(long, default_value_t = 3000)]
    pub silent_ms: u64,
}

/// A ROS 2 robot's arm, as the arm driver.
pub struct Ros2Arm;

impl FixedPorts for Ros2Arm {
    const PORTS: Ports<'static> = DRIVER_PORTS;
}

impl Stage for Ros2Arm {
    type Args = ArmArgs;
    const BINARY: &'static str = "ros2_proc";
    const SUBCOMMAND: Option<&'static str> = Some("arm");
    const HOME: Home = Home::On(Side::Robot);
    const SAMPLE_PATH_DEPTH: Option<u8> = Some(5);
    const SOURCE: bool = true;
    /// It stops when the plan is finished.
    const RESTART: RestartPolicy = RestartPolicy::Finishes;
    const STOP_GRACE: Duration = Duration::from_secs(3);

    fn ports(_: &ArmArgs) -> Ports<'_> {
        Self::PORTS
    }

    fn prefix(args: &ArmArgs) -> &str {
        &args.prefix
    }

    fn example() -> ArmArgs {
        ArmArgs {
            prefix: "p".into(),
            rig: "r.toml".into(),
            graph: Graph {
                endpoint: "tls/10.0.0.2:7447".into(),
                domain: 7,
                namespace: "/robot1".into(),
                tls_ca: Some("certs/ca.pem".into()),
                tls_cert: Some("certs/client.pem".into()),
                tls_key: Some("certs/client.key".into()),
            },
            joint_states: "joint_states".into(),
            trajectory: "/arm_controller/joint_trajectory".into(),
            move_ms: 450,
            silent_ms: 2000,
        }
    }
}

/// Publish each calibration on `/tf_static` (latched) and each located
/// object as a `geometry_msgs/PointStamped`.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
pub struct TfArgs {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    pub prefix: String,
    /// Rig file (TOML): the cameras' intrinsics and poses.
    #[arg(long)]
    pub rig: PathBuf,
    /// The graph.
    #[command(flatten)]
    #[serde(flatten)]
    pub graph: Graph,
    /// Topic of the latched transforms.
    #[arg(long, default_value = "/tf_static")]
    pub tf_static: String,
    /// Topic of the located objects.
    #[arg(long, default_value = "/mirror/located")]
    pub located: String,
}

/// The calibration and located objects out to a ROS 2 graph.
pub struct Ros2Tf;

impl FixedPorts for Ros2Tf {
    const PORTS: Ports<'static> = Ports {
        subscribes: &[TopicId::Calibration, TopicId::Located],
        publishes: &[],
    };
}

impl Stage for Ros2Tf {
    type Args = TfArgs;
    const BINARY: &'static str = "ros2_proc";
    const SUBCOMMAND: Option<&'static str> = Some("tf");
    /// Where the calibrations are made.
    const HOME: Home = Home::On(Side::Workstation);
    const SAMPLE_PATH_DEPTH: Option<u8> = None;
    const RESTART: RestartPolicy = RestartPolicy::Service;

    fn ports(_: &TfArgs) -> Ports<'_> {
        Self::PORTS
    }

    fn prefix(args: &TfArgs) -> &str {
        &args.prefix
    }

    fn example() -> TfArgs {
        TfArgs {
            prefix: "p".into(),
            rig: "r.toml".into(),
            graph: Graph {
                endpoint: "tls/10.0.0.2:7447".into(),
                domain: 3,
                namespace: "/".into(),
                tls_ca: Some("ca.pem".into()),
                tls_cert: None,
                tls_key: None,
            },
            tf_static: "/tf_static".into(),
            located: "/robot1/located".into(),
        }
    }
}

/// Be the stereo camera: pair a ROS 2 camera's left and right
/// `sensor_msgs/Image` topics by stamp and publish each pair as a frame.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
pub struct CameraArgs {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    pub prefix: String,
    /// The graph.
    #[command(flatten)]
    #[serde(flatten)]
    pub graph: Graph,
    /// The left camera's image topic.
    #[arg(long, default_value = "/left/image_raw")]
    pub left: String,
    /// The right camera's image topic.
    #[arg(long, default_value = "/right/image_raw")]
    pub right: String,
    /// Two images are a pair when their header stamps differ by at most
    /// this, ms (hardware-synchronised cameras: 0; free-running ones: up to
    /// half a frame period).
    #[arg(long, default_value_t = 5.0)]
    pub tolerance_ms: f64,
}

/// A ROS 2 stereo camera as the camera stage.
pub struct Ros2Camera;

impl FixedPorts for Ros2Camera {
    const PORTS: Ports<'static> = Ports {
        subscribes: &[],
        publishes: &[TopicId::Frames],
    };
}

impl Stage for Ros2Camera {
    type Args = CameraArgs;
    const BINARY: &'static str = "ros2_proc";
    const SUBCOMMAND: Option<&'static str> = Some("camera");
    const HOME: Home = Home::On(Side::Robot);
    const SAMPLE_PATH_DEPTH: Option<u8> = Some(5);
    const SOURCE: bool = true;
    /// A live camera runs until the run ends.
    const RESTART: RestartPolicy = RestartPolicy::Service;

    fn ports(_: &CameraArgs) -> Ports<'_> {
        Self::PORTS
    }

    fn prefix(args: &CameraArgs) -> &str {
        &args.prefix
    }

    fn example() -> CameraArgs {
        CameraArgs {
            prefix: "p".into(),
            graph: Graph {
                endpoint: "tcp/10.0.0.2:7447".into(),
                domain: 4,
                namespace: "/head".into(),
                ..Graph::default()
            },
            left: "stereo/left/image_rect".into(),
            right: "/stereo/right/image_rect".into(),
            tolerance_ms: 2.5,
        }
    }
}
