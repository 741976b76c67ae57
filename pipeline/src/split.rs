//! A run split across two hosts: which stages run on the robot and which on
//! the workstation, and what the bridge between the two sides carries.
//!
//! Both sides read the same config and build the same stage table; each
//! starts its own part of it and a `bridge`. What crosses follows from the
//! table (see [`crossing`]), so the two sides agree on it without a word.

use messages::topics::TopicId;
use serde::{Deserialize, Serialize};

use crate::stages::StageArgs;

/// One side of a split run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    /// The host with the camera and the arm: camera, arm driver,
    /// kinematics (and the tracker, unless offloaded).
    #[default]
    Robot,
    /// The host that calibrates and records: mirror stage and recorder
    /// (and the tracker, if offloaded).
    Workstation,
}

impl Side {
    /// The side across the link.
    pub fn other(self) -> Side {
        match self {
            Side::Robot => Side::Workstation,
            Side::Workstation => Side::Robot,
        }
    }

    /// Its name in logs.
    pub fn name(self) -> &'static str {
        match self {
            Side::Robot => "robot",
            Side::Workstation => "workstation",
        }
    }
}

/// How frames cross the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameCompression {
    /// As in shared memory.
    #[default]
    None,
    /// Lossless zstd (level 1): about 3/4 of the bytes for 2 ms a frame.
    Zstd,
}

/// The config's `[split]` table: what both sides of a split run must agree
/// on. The link's endpoints differ per side and come from the command line.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SplitConfig {
    /// Where the tracker runs: on the robot (default; only detections
    /// cross, and frames only for the workstation's recorder), or on the
    /// workstation (offload: every frame crosses).
    pub tracker: Side,
    /// How frames cross.
    pub compress_frames: FrameCompression,
    /// How long the link may stay silent before it counts as cut, ms
    /// (absent: the bridge's default).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lease_ms: Option<u64>,
}

/// This host's side of a split run and where its link goes (the command
/// line's part).
#[derive(Debug, Clone)]
pub struct Link {
    /// This host's side.
    pub side: Side,
    /// Zenoh endpoints to listen on.
    pub listen: Vec<String>,
    /// Zenoh endpoints to connect to.
    pub connect: Vec<String>,
    /// First part of the bridge's keys (each placement appends `/m<i>`);
    /// both sides give the same, a second robot another.
    pub namespace: String,
}

/// The namespace of a split run unless `--namespace` says.
pub const DEFAULT_NAMESPACE: &str = "mirror/split";

/// The `bridge` stage's arguments.
#[derive(Debug, Clone)]
pub struct BridgeArgs {
    /// Zenoh key namespace.
    pub namespace: String,
    /// Topics sent to the other side.
    pub send: Vec<TopicId>,
    /// Topics received from it.
    pub receive: Vec<TopicId>,
    /// Endpoints to listen on.
    pub listen: Vec<String>,
    /// Endpoints to connect to.
    pub connect: Vec<String>,
    /// How frames cross.
    pub compress_frames: FrameCompression,
    /// Lease, ms (absent: the bridge's default).
    pub lease_ms: Option<u64>,
}

impl BridgeArgs {
    /// The command line after `--prefix P`.
    pub fn argv(&self) -> Vec<String> {
        let topics = |t: &[TopicId]| t.iter().map(|t| t.name()).collect::<Vec<_>>().join(",");
        let mut argv = vec!["--namespace".to_string(), self.namespace.clone()];
        for (flag, list) in [("--send", &self.send), ("--receive", &self.receive)] {
            if !list.is_empty() {
                argv.extend([flag.to_string(), topics(list)]);
            }
        }
        for (flag, endpoints) in [("--listen", &self.listen), ("--connect", &self.connect)] {
            for e in endpoints {
                argv.extend([flag.to_string(), e.clone()]);
            }
        }
        if self.compress_frames == FrameCompression::Zstd {
            argv.extend(["--compress-frames".into(), "zstd".into()]);
        }
        if let Some(ms) = self.lease_ms {
            argv.extend(["--lease-ms".into(), ms.to_string()]);
        }
        argv
    }
}

/// The side a stage of the whole run's table runs on.
pub fn side_of(stage: &StageArgs, config: &SplitConfig) -> Side {
    match stage {
        StageArgs::Camera { .. } | StageArgs::ArmDriver { .. } | StageArgs::Kinematics { .. } => {
            Side::Robot
        }
        StageArgs::Tracker => config.tracker,
        StageArgs::Recorder { .. }
        | StageArgs::Mirror { .. }
        | StageArgs::Replay { .. }
        | StageArgs::Bridge(_) => Side::Workstation,
    }
}

/// The topics that cross from the stages `from` to the stages `to`: every
/// small topic published on `from` (they are cheap, and the robot gets the
/// calibration, the predictions and the located objects for its own use
/// even when none of its stages reads them), and frames only when a stage
/// on `to` reads them.
pub fn crossing(from: &[&StageArgs], to: &[&StageArgs]) -> Vec<TopicId> {
    TopicId::ALL
        .into_iter()
        .filter(|t| from.iter().any(|s| s.publishes().contains(t)))
        .filter(|t| !t.carries_frames() || to.iter().any(|s| s.subscribes().contains(t)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Look;
    use mirror_proc::calibrate::Method;

    /// The whole run's table, as the launcher builds it.
    fn table(record: bool) -> Vec<StageArgs> {
        let mut stages = Vec::new();
        if record {
            stages.push(StageArgs::Recorder {
                out: "r.mcap".into(),
                no_drop: false,
                rig: "rig.toml".into(),
                attach: vec![],
                meta: vec![],
                live_view: None,
            });
        }
        stages.extend([
            StageArgs::Mirror {
                rig: "rig.toml".into(),
                method: Method::Joint,
                min_train: 8,
                report: "report.json".into(),
                journal: "j.mcap".into(),
            },
            StageArgs::Tracker,
            StageArgs::Camera {
                mirror: 0,
                fps: 30.0,
                look: Look::Realistic,
            },
            StageArgs::ArmDriver {
                rig: "rig.toml".into(),
                command: None,
                move_ms: 100,
                rate_hz: 250.0,
            },
            StageArgs::Kinematics {
                rig: "rig.toml".into(),
                plan: "plan.csv".into(),
                dwell_ms: 250,
                wait_subscribers: 1,
                journal: "a.mcap".into(),
            },
        ]);
        stages
    }

    fn sides<'a>(
        stages: &'a [StageArgs],
        config: &SplitConfig,
    ) -> (Vec<&'a StageArgs>, Vec<&'a StageArgs>) {
        stages
            .iter()
            .partition(|s| side_of(s, config) == Side::Robot)
    }

    fn names(topics: &[TopicId]) -> Vec<&'static str> {
        topics.iter().map(|t| t.name()).collect()
    }

    #[test]
    fn what_crosses_follows_from_where_the_stages_run() {
        let config = SplitConfig::default();
        let stages = table(true);
        let (robot, workstation) = sides(&stages, &config);
        // The recorder on the workstation reads every topic: all cross.
        assert_eq!(
            names(&crossing(&robot, &workstation)),
            [
                "frames",
                "detections",
                "joint_state",
                "joint_positions",
                "pose_goal"
            ]
        );
        assert_eq!(
            names(&crossing(&workstation, &robot)),
            ["samples", "calibration", "predictions", "located"]
        );
        // Without the recorder nobody there reads frames: they stay.
        let stages = table(false);
        let (robot, workstation) = sides(&stages, &config);
        assert_eq!(
            names(&crossing(&robot, &workstation)),
            ["detections", "joint_state", "joint_positions", "pose_goal"]
        );
        // The tracker offloaded: frames go, detections come back.
        let offload = SplitConfig {
            tracker: Side::Workstation,
            ..SplitConfig::default()
        };
        let (robot, workstation) = sides(&stages, &offload);
        assert_eq!(
            names(&crossing(&robot, &workstation)),
            ["frames", "joint_state", "joint_positions", "pose_goal"]
        );
        assert_eq!(
            names(&crossing(&workstation, &robot)),
            [
                "detections",
                "samples",
                "calibration",
                "predictions",
                "located"
            ]
        );
    }

    #[test]
    fn the_bridge_command_line_follows_its_arguments() {
        let bridge = BridgeArgs {
            namespace: "mirror/split/m0".into(),
            send: vec![TopicId::Frames, TopicId::JointState],
            receive: vec![TopicId::Samples],
            listen: vec!["tcp/0.0.0.0:7447".into()],
            connect: vec![],
            compress_frames: FrameCompression::Zstd,
            lease_ms: Some(2000),
        };
        assert_eq!(
            StageArgs::Bridge(bridge).argv("p").join(" "),
            "--prefix p --namespace mirror/split/m0 --send frames,joint_state --receive samples \
             --listen tcp/0.0.0.0:7447 --compress-frames zstd --lease-ms 2000"
        );
    }
}
