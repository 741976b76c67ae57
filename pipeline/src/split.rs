//! A run split across two hosts: which stages run on the robot and which on
//! the workstation, and what the bridge between the two sides carries.
//!
//! Both sides read the same config and build the same stage table; each
//! starts its own part of it and a `bridge`. What crosses follows from the
//! table (see [`crossing`]), so the two sides agree on it without a word.

use std::path::PathBuf;

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
    /// The run's certificates (`pipeline certs`), relative to the config
    /// file; each side reads its own from the directory it has.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub certs: Option<PathBuf>,
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
    /// The run's certificates: the link is mutual TLS.
    pub certs: Option<PathBuf>,
    /// Plain TCP across hosts is allowed.
    pub insecure: bool,
}

impl Link {
    /// Refuses, before anything starts, a link that the bridge would refuse:
    /// a `tls/` endpoint without certificates, certificates without one,
    /// plain TCP to or from another host without `--insecure`, or this
    /// side's certificate files missing or open to others.
    pub fn check(&self) -> Result<(), secure_link::LinkError> {
        let endpoints = [&self.listen[..], &self.connect[..]].concat();
        secure_link::endpoint::check(
            &endpoints,
            self.certs.is_some(),
            self.insecure,
            stages::bridge::EXPOSED_ON_PLAIN_TCP,
        )?;
        match &self.certs {
            Some(dir) => secure_link::tls::Identity::of_side(dir, self.side.name()).check(),
            None => Ok(()),
        }
    }
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
    fn a_link_across_hosts_needs_the_runs_certificates_or_insecure() {
        let link = |endpoint: &str, certs: Option<PathBuf>, insecure: bool| Link {
            side: Side::Robot,
            listen: vec![endpoint.into()],
            connect: Vec::new(),
            namespace: DEFAULT_NAMESPACE.into(),
            certs,
            insecure,
        };
        let err = link("tcp/0.0.0.0:7447", None, false).check().unwrap_err();
        assert!(err.to_string().contains("--insecure"), "{err}");
        link("tcp/0.0.0.0:7447", None, true).check().unwrap();
        link("tcp/127.0.0.1:7447", None, false).check().unwrap();
        // This side's files are checked before anything starts.
        let dir = tempfile::tempdir().unwrap();
        let err = link("tls/0.0.0.0:7447", Some(dir.path().into()), false)
            .check()
            .unwrap_err();
        assert!(err.to_string().contains("ca.pem"), "{err}");
        let sides = ["robot", "workstation"].map(|name| secure_link::certs::SideRequest {
            name: name.into(),
            hosts: vec!["localhost".into()],
        });
        secure_link::certs::write(dir.path(), &sides, 1, false).unwrap();
        link("tls/0.0.0.0:7447", Some(dir.path().into()), false)
            .check()
            .unwrap();
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
