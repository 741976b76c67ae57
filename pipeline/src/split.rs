//! A run split across two hosts: which stages run on the robot and which on
//! the workstation, and what the bridge between the two sides carries.
//!
//! Both sides read the same config and build the same stage table; each
//! starts its own part of it and a `bridge`. What crosses follows from the
//! table (see [`crossing`]), so the two sides agree on it without a word.

use messages::topics::TopicId;
use serde::{Deserialize, Serialize};
pub use stages::Side;
pub use stages::bridge::FrameCompression;
use stages::{Home, StageArgs};

/// The config's `[split]` table: what both sides of a split run must agree
/// on. The link's endpoints differ per side and come from the command line.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SplitConfig {
    /// Where the tracker (the offloadable stage) runs: on the robot
    /// (default; only detections cross, and frames only for the
    /// workstation's recorder), or on the workstation (offload: every frame
    /// crosses).
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

/// The side a stage of the whole run's table runs on: its declaration's
/// [`Home`], and for the offloadable stage the side the config gives it.
pub fn side_of(stage: &StageArgs, config: &SplitConfig) -> Side {
    match stage.home() {
        Home::On(side) => side,
        Home::Offloadable => config.tracker,
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

    /// The whole run's table, as the launcher builds it.
    fn table(record: bool) -> Vec<StageArgs> {
        let mut table: Vec<StageArgs> = Vec::new();
        if record {
            table.push(stages::recorder::Args::default().into());
        }
        table.extend([
            stages::mirror::Args::new("p", "rig.toml").into(),
            stages::tracker::Args::default().into(),
            stages::camera::Args::default().into(),
            stages::sim_arm::Args {
                prefix: "p".into(),
                rig: "rig.toml".into(),
                move_ms: 100,
                rate_hz: 250.0,
            }
            .into(),
            stages::kinematics::Args::new("p", "rig.toml").into(),
        ]);
        table
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
}
