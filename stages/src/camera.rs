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
    const SAMPLE_PATH_DEPTH: Option<u8> = Some(0);
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
            ..Default::default()
        }
    }
}
