//! `camera_proc sim`: the simulated head, rendering what it sees.

use messages::topics::TopicId;
use runtime::Ports;
use serde::{Deserialize, Serialize};

use crate::{FixedPorts, Home, RestartPolicy, Side, Stage};

/// What the simulated camera's images look like: a named preset of
/// `renderer::look::Look`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum LookName {
    /// A room, the mirror's frame, the robot; a real camera's blur and noise.
    #[default]
    Realistic,
    /// Cards on a flat grey field with light blur and noise.
    Clean,
    /// Cards on a flat grey field, no blur, no noise.
    Sharp,
}

impl LookName {
    /// Every preset, in the order of the help text.
    pub const ALL: [LookName; 3] = [LookName::Realistic, LookName::Clean, LookName::Sharp];

    /// The name as written in configs and on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            LookName::Realistic => "realistic",
            LookName::Clean => "clean",
            LookName::Sharp => "sharp",
        }
    }
}

impl std::fmt::Display for LookName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A look name that is none of [`LookName::ALL`]'s.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown look {0:?} (realistic, clean, sharp)")]
pub struct UnknownLook(pub String);

impl std::str::FromStr for LookName {
    type Err = UnknownLook;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        LookName::ALL
            .into_iter()
            .find(|l| l.as_str() == s)
            .ok_or_else(|| UnknownLook(s.to_string()))
    }
}

/// A camera's own axis it may be turned about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraAxis {
    /// Its x axis (right): the view tilts up or down.
    Tilt,
    /// Its y axis (down): the view pans left or right.
    #[default]
    Pan,
    /// Its z axis: the view turns about the optical axis.
    Roll,
}

impl CameraAxis {
    /// Every axis, x, y, z.
    pub const ALL: [CameraAxis; 3] = [CameraAxis::Tilt, CameraAxis::Pan, CameraAxis::Roll];

    /// The name in configs and on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            CameraAxis::Tilt => "tilt",
            CameraAxis::Pan => "pan",
            CameraAxis::Roll => "roll",
        }
    }

    /// 0, 1, 2 for x, y, z.
    pub fn index(self) -> usize {
        self as usize
    }
}

/// A change of the simulated world (`--change`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Change {
    /// The mirror turns `tilt_deg` about its width axis and moves
    /// `shift_mm` along its normal, towards the robot.
    Mirror {
        /// Turn, degrees.
        tilt_deg: f64,
        /// Shift, mm.
        shift_mm: f64,
    },
    /// Head camera `camera` (0 left, 1 right) turns `rotate_deg` about
    /// its own `axis`.
    Camera {
        /// Which camera.
        camera: usize,
        /// Turn, degrees.
        rotate_deg: f64,
        /// About which of its axes.
        axis: CameraAxis,
    },
}

impl From<Change> for geometry::sim::WorldChange {
    fn from(change: Change) -> Self {
        match change {
            Change::Mirror { tilt_deg, shift_mm } => Self::Mirror { tilt_deg, shift_mm },
            Change::Camera {
                camera,
                rotate_deg,
                axis,
            } => Self::Camera {
                camera,
                rotate_deg,
                axis: axis.index(),
            },
        }
    }
}

/// A change of the world from the goal of pose `pose` on:
/// `POSE:mirror:TILT_DEG:SHIFT_MM` or `POSE:camera:INDEX:DEG:AXIS`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChangeAt {
    /// The pose id from whose goal on the world is changed.
    pub pose: u64,
    /// What changes.
    pub change: Change,
}

impl std::fmt::Display for ChangeAt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.change {
            Change::Mirror { tilt_deg, shift_mm } => {
                write!(f, "{}:mirror:{tilt_deg}:{shift_mm}", self.pose)
            }
            Change::Camera {
                camera,
                rotate_deg,
                axis,
            } => write!(
                f,
                "{}:camera:{camera}:{rotate_deg}:{}",
                self.pose,
                axis.as_str()
            ),
        }
    }
}

impl std::str::FromStr for ChangeAt {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = |why: &str| {
            format!("{s:?}: {why} (POSE:mirror:TILT_DEG:SHIFT_MM or POSE:camera:INDEX:DEG:AXIS)")
        };
        let number = |word: &str, what: &str| -> Result<f64, String> {
            word.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(&format!("{what} {word:?} is not a number")))
        };
        let words: Vec<&str> = s.split(':').collect();
        let pose = words[0]
            .parse()
            .map_err(|_| bad(&format!("pose {:?} is not a pose id", words[0])))?;
        let change = match words[1..] {
            ["mirror", tilt, shift] => Change::Mirror {
                tilt_deg: number(tilt, "tilt")?,
                shift_mm: number(shift, "shift")?,
            },
            ["camera", camera, deg, axis] => Change::Camera {
                camera: match camera {
                    "0" => 0,
                    "1" => 1,
                    _ => return Err(bad("the camera index is 0 (left) or 1 (right)")),
                },
                rotate_deg: number(deg, "turn")?,
                axis: CameraAxis::ALL
                    .into_iter()
                    .find(|a| a.as_str() == axis)
                    .ok_or_else(|| bad("the axis is tilt, pan or roll"))?,
            },
            _ => return Err(bad("not a change")),
        };
        Ok(Self { pose, change })
    }
}

impl Serialize for ChangeAt {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// Render what the simulated head sees, following the arm's joint states.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
pub struct Args {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    pub prefix: String,
    /// Mirror placement of the Nico scene (0, 1, 2).
    #[arg(long, default_value_t = 0)]
    pub mirror: usize,
    /// Frame rate, Hz.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Frames to keep rendering after the pose plan is done.
    #[arg(long, default_value_t = 5)]
    pub tail_frames: u32,
    /// What the images look like: a room and a real camera's blur and
    /// noise, or cards on a flat grey field.
    #[arg(long, value_enum, default_value_t = LookName::Realistic)]
    pub look: LookName,
    /// Compress each image with JPEG at this quality (1-100), as a USB
    /// camera's MJPEG stream does.
    #[arg(long, value_name = "QUALITY", value_parser = clap::value_parser!(u8).range(1..=100))]
    pub mjpeg: Option<u8>,
    /// Change the world from the goal of a pose on, as a bumped mirror or a
    /// knocked camera would: `POSE:mirror:TILT_DEG:SHIFT_MM` (turned about
    /// its width axis, then moved along its normal towards the robot) or
    /// `POSE:camera:INDEX:DEG:AXIS` (camera 0 or 1 turned about its own
    /// tilt, pan or roll axis). Repeat for more, in plan order; each adds
    /// to those before.
    #[arg(long = "change", value_name = "SPEC")]
    pub changes: Vec<ChangeAt>,
}

impl Default for Args {
    fn default() -> Self {
        Self {
            prefix: "default".into(),
            mirror: 0,
            fps: 30.0,
            tail_frames: 5,
            look: LookName::Realistic,
            mjpeg: None,
            changes: Vec::new(),
        }
    }
}

/// The simulated camera's declaration.
pub struct Camera;

impl FixedPorts for Camera {
    /// It renders the arm where the driver's positions put it, and knows
    /// from the goals when the plan is done.
    const PORTS: Ports<'static> = Ports {
        subscribes: &[TopicId::JointPositions, TopicId::PoseGoal],
        publishes: &[TopicId::Frames],
    };
}

impl Stage for Camera {
    type Args = Args;
    const BINARY: &'static str = "camera_proc";
    const SUBCOMMAND: Option<&'static str> = Some("sim");
    const HOME: Home = Home::On(Side::Robot);
    // Above the tracker: it stands for a camera, whose frame clock nothing
    // on the computer delays (see `Stage::SAMPLE_PATH_DEPTH`).
    const SAMPLE_PATH_DEPTH: Option<u8> = Some(2);
    const SOURCE: bool = true;
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
            mirror: 2,
            fps: 29.97,
            look: LookName::Clean,
            mjpeg: Some(80),
            changes: vec![
                ChangeAt {
                    pose: 10_004,
                    change: Change::Mirror {
                        tilt_deg: 1.0,
                        shift_mm: -2.5,
                    },
                },
                ChangeAt {
                    pose: 30_002,
                    change: Change::Camera {
                        camera: 0,
                        rotate_deg: 0.3,
                        axis: CameraAxis::Roll,
                    },
                },
            ],
            ..Default::default()
        }
    }
}
