//! `tracker_proc run`: ArUco markers, printed and mirror-reversed, in stereo frames.

use messages::topics::TopicId;
use runtime::Ports;
use serde::Serialize;

use crate::{FixedPorts, Home, RestartPolicy, Stage};

/// Subscribe to stereo frames and publish detections.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
pub struct Args {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    pub prefix: String,
    /// Only find markers as printed (no mirror-reversed ones).
    #[arg(long)]
    pub no_mirrored: bool,
    /// Search each image whole every N frames, and in between only
    /// around the markers of the last frame, with a low-resolution
    /// look-out over the whole image (a marker not seen anywhere brings
    /// the full scan forward); a frame's whole search is made after its
    /// detections are published. 1 searches every frame whole.
    #[arg(long, value_name = "N", default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..))]
    pub full_scan_every: u32,
}

impl Default for Args {
    fn default() -> Self {
        Self {
            prefix: "default".into(),
            no_mirrored: false,
            full_scan_every: 10,
        }
    }
}

/// The tracker's declaration.
pub struct Tracker;

impl FixedPorts for Tracker {
    const PORTS: Ports<'static> = Ports {
        subscribes: &[TopicId::Frames],
        publishes: &[TopicId::Detections],
    };
}

impl Stage for Tracker {
    type Args = Args;
    const BINARY: &'static str = "tracker_proc";
    const SUBCOMMAND: Option<&'static str> = Some("run");
    const HOME: Home = Home::Offloadable;
    const SAMPLE_PATH_DEPTH: Option<u8> = Some(1);
    const RESTART: RestartPolicy = RestartPolicy::Service;

    fn ports(_: &Args) -> Ports<'_> {
        Self::PORTS
    }

    fn prefix(args: &Args) -> &str {
        &args.prefix
    }

    fn example() -> Args {
        Args {
            prefix: "p".into(),
            no_mirrored: true,
            full_scan_every: 4,
        }
    }
}
