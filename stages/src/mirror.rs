//! `mirror_proc run`: pairs joint states with detections, calibrates the
//! mirror, predicts and locates.

use std::path::PathBuf;

use formats::calibration::Method;
use messages::topics::TopicId;
use runtime::Ports;
use serde::Serialize;

use crate::{FixedPorts, Home, RestartPolicy, Side, Stage};

/// Calibrate live from joint states and detections.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
pub struct Args {
    /// Service prefix of the pipeline.
    #[arg(long, default_value = "default")]
    pub prefix: String,
    /// Rig file (TOML).
    #[arg(long)]
    pub rig: PathBuf,
    /// paper | joint | joint+kinematics.
    #[arg(long, default_value = "joint+kinematics")]
    pub method: Method,
    /// Training samples before the first calibration.
    #[arg(long, default_value_t = 8)]
    pub min_train: usize,
    /// Wait after a pose settles before pairing a frame with it, ms.
    #[arg(long, default_value_t = 30)]
    pub settle_ms: i64,
    /// Write the final report (JSON) here when the pose plan ends.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Journal every paired sample and calibration here (MCAP) before
    /// publishing it; if the file exists, resume from it first (a
    /// restarted stage loses nothing it had collected). Give a new path
    /// for a new calibration.
    #[arg(long)]
    pub journal: Option<PathBuf>,
    /// Do not watch new samples for a changed world. By default each new
    /// sample is scored against the calibration; a moved mirror or a
    /// knocked camera found ends the calibration's epoch (the calibration
    /// goes out once more, drifted) and the stage calibrates again from
    /// the samples that follow.
    #[arg(long)]
    pub no_drift_watch: bool,
}

impl Args {
    /// The arguments with their defaults, for `prefix` and `rig`.
    pub fn new(prefix: impl Into<String>, rig: impl Into<PathBuf>) -> Self {
        Self {
            prefix: prefix.into(),
            rig: rig.into(),
            method: Method::JointKinematics,
            min_train: 8,
            settle_ms: 30,
            report: None,
            journal: None,
            no_drift_watch: false,
        }
    }
}

/// The mirror stage's declaration.
pub struct Mirror;

impl FixedPorts for Mirror {
    const PORTS: Ports<'static> = Ports {
        subscribes: &[TopicId::JointState, TopicId::Detections],
        publishes: &[
            TopicId::Samples,
            TopicId::Calibration,
            TopicId::Predictions,
            TopicId::Located,
        ],
    };
}

impl Stage for Mirror {
    type Args = Args;
    const BINARY: &'static str = "mirror_proc";
    const SUBCOMMAND: Option<&'static str> = Some("run");
    const HOME: Home = Home::On(Side::Workstation);
    const SAMPLE_PATH_DEPTH: Option<u8> = Some(4);
    /// It exits when the plan has ended and it has processed everything.
    const RESTART: RestartPolicy = RestartPolicy::Finishes;

    fn ports(_: &Args) -> Ports<'_> {
        Self::PORTS
    }

    fn prefix(args: &Args) -> &str {
        &args.prefix
    }

    fn example() -> Args {
        Args {
            method: Method::Joint,
            report: Some("out/report.json".into()),
            journal: Some("out/journal.mcap".into()),
            min_train: 12,
            no_drift_watch: true,
            ..Args::new("p", "r.toml")
        }
    }
}
