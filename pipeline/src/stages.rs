//! The stages of a placement's run, as a table of specs: which binary, its
//! typed arguments, its restart policy and the topics it subscribes to.
//! Start order, readiness, restarts and stop order all derive from it.

use std::path::PathBuf;
use std::time::Duration;

use messages::topics::TopicId;
use mirror_proc::calibrate::Method;

use crate::split::BridgeArgs;

use crate::config::Look;

/// What a stage's exit means, and whether it is started again. (Which
/// stage's successful exit ends the run is the launcher's choice: see
/// [`crate::supervise::Supervisor::new`].)
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RestartPolicy {
    /// Runs until the run ends: any exit is a crash, restarted.
    Service,
    /// May finish by itself (exit 0); a failure is restarted.
    Finishes,
    /// Never restarted (a restart would overwrite its output); if it
    /// stops, the run goes on without it.
    Optional,
}

/// Restarts allowed per stage before the run fails.
pub const MAX_RESTARTS: u32 = 3;

/// Each stage binary's arguments, typed.
#[derive(Debug, Clone)]
pub enum StageArgs {
    /// `recorder`: every topic into one MCAP file.
    Recorder {
        /// The recording.
        out: PathBuf,
        /// Never drop a frame (a replay waits for the recorder instead).
        no_drop: bool,
        /// The rig, for the viewing channels and as an attachment.
        rig: PathBuf,
        /// More files to attach.
        attach: Vec<PathBuf>,
        /// `run` metadata, KEY=VALUE.
        meta: Vec<(String, String)>,
        /// Serve the live view on this localhost port.
        live_view: Option<u16>,
    },
    /// `mirror_proc run`: pairing, calibration, predictions.
    Mirror {
        /// The rig.
        rig: PathBuf,
        /// Calibration method.
        method: Method,
        /// Training samples before the first calibration.
        min_train: usize,
        /// Where the final report goes.
        report: PathBuf,
        /// Its journal: a restart resumes from it.
        journal: PathBuf,
    },
    /// `tracker_proc run`: ArUco detection.
    Tracker,
    /// `camera_proc sim`: the simulated head.
    Camera {
        /// Mirror placement.
        mirror: usize,
        /// Frame rate, Hz.
        fps: f64,
        /// What the images look like (`realistic`, `clean`, `sharp`).
        look: Look,
    },
    /// `replay`: a recording's frames or detections, and its joint states,
    /// back onto the topics, in lockstep with the slowest subscriber.
    Replay {
        /// The recording.
        file: PathBuf,
        /// What it publishes.
        kind: recorder::replay::Kind,
        /// Subscribers each replayed topic waits for.
        wait_subscribers: usize,
    },
    /// The arm driver: `sim_arm`, or the user's command.
    ArmDriver {
        /// The rig.
        rig: PathBuf,
        /// The user's driver command, split into words; `None`: `sim_arm`.
        command: Option<Vec<String>>,
        /// Move time of `sim_arm`, ms.
        move_ms: u64,
        /// Joint-position rate of `sim_arm`, Hz.
        rate_hz: f64,
    },
    /// `kinematics_proc`: the pose plan, through the arm driver.
    Kinematics {
        /// The rig.
        rig: PathBuf,
        /// The pose plan.
        plan: PathBuf,
        /// Dwell time at each pose, ms.
        dwell_ms: u64,
        /// Joint-state subscribers to wait for before moving.
        wait_subscribers: usize,
        /// Its journal: a restart takes up the plan after the last pose reached.
        journal: PathBuf,
    },
    /// `bridge`: this side's topics to the other host of a split run, and
    /// the other side's here.
    Bridge(BridgeArgs),
}

/// How much the recorder gives way to the other stages: see
/// [`StageArgs::niceness`].
pub const RECORDER_NICENESS: i32 = 10;

impl StageArgs {
    /// The stage's name in logs and reports: its binary's, or `arm_driver`
    /// for a user's driver.
    pub fn binary(&self) -> &'static str {
        match self {
            StageArgs::ArmDriver { command: None, .. } => "sim_arm",
            StageArgs::Replay { .. } => "replay",
            StageArgs::ArmDriver { .. } => "arm_driver",
            StageArgs::Recorder { .. } => "recorder",
            StageArgs::Mirror { .. } => "mirror_proc",
            StageArgs::Tracker => "tracker_proc",
            StageArgs::Camera { .. } => "camera_proc",
            StageArgs::Kinematics { .. } => "kinematics_proc",
            StageArgs::Bridge(_) => "bridge",
        }
    }

    /// The stage's scheduling niceness (0: the launcher's own). A live
    /// run's recorder is the one stage no sample waits for: on a busy
    /// machine it gives way to the stages on the path from frame to sample,
    /// and its queue takes up the delay. A replay's recorder (`no_drop`) is
    /// on the replay's path, and must be subscribed to everything before
    /// the replayed messages come: it keeps the launcher's priority.
    pub fn niceness(&self) -> i32 {
        match self {
            StageArgs::Recorder { no_drop: false, .. } => RECORDER_NICENESS,
            _ => 0,
        }
    }

    /// For a stage every sample waits for, how far down the path from
    /// camera to sample it sits: the camera and the arm driver 0 (a frame's
    /// stamp is its capture; a frame is paired once a joint state stamped
    /// after it has come), the tracker, the kinematics and (in a split run)
    /// the bridge 1, the mirror stage 2. At real-time priority
    /// ([`crate::config::Config::realtime_priority`]) each runs that much
    /// above the base, so that a frame further along is never kept waiting
    /// by one behind it: the mirror stage pairs a frame's detections while
    /// the tracker's periodic full scan of that frame goes on. `None`: no
    /// sample waits for it (the recorder, a replay).
    pub fn sample_path_depth(&self) -> Option<u8> {
        match self {
            StageArgs::Camera { .. } | StageArgs::ArmDriver { .. } => Some(0),
            StageArgs::Tracker | StageArgs::Kinematics { .. } | StageArgs::Bridge(_) => Some(1),
            StageArgs::Mirror { .. } => Some(2),
            StageArgs::Recorder { .. } | StageArgs::Replay { .. } => None,
        }
    }

    /// The topics the stage subscribes to (its binary's contract).
    pub fn subscribes(&self) -> &[TopicId] {
        match self {
            StageArgs::Recorder { .. } => &TopicId::ALL,
            StageArgs::Mirror { .. } => &[TopicId::JointState, TopicId::Detections],
            StageArgs::Tracker => &[TopicId::Frames],
            StageArgs::Camera { .. } => &[TopicId::JointPositions, TopicId::PoseGoal],
            StageArgs::ArmDriver { .. } => &[TopicId::PoseGoal],
            StageArgs::Replay { .. } => &[],
            StageArgs::Kinematics { .. } => &[TopicId::JointPositions],
            StageArgs::Bridge(b) => &b.send,
        }
    }

    /// The topics the stage publishes (its binary's contract).
    pub fn publishes(&self) -> &[TopicId] {
        match self {
            StageArgs::Recorder { .. } => &[],
            StageArgs::Mirror { .. } => &[
                TopicId::Samples,
                TopicId::Calibration,
                TopicId::Predictions,
                TopicId::Located,
            ],
            StageArgs::Tracker => &[TopicId::Detections],
            StageArgs::Camera { .. } => &[TopicId::Frames],
            StageArgs::ArmDriver { .. } => &[TopicId::JointPositions],
            StageArgs::Replay { kind, .. } => kind.topics(),
            StageArgs::Kinematics { .. } => &[TopicId::JointState, TopicId::PoseGoal],
            StageArgs::Bridge(b) => &b.receive,
        }
    }

    /// The program to run: a workspace binary in `bin_dir`, or the first
    /// word of a user's driver command (found on `PATH` if it has no `/`).
    pub fn program(&self, bin_dir: &std::path::Path) -> PathBuf {
        match self {
            StageArgs::ArmDriver {
                command: Some(words),
                ..
            } => PathBuf::from(&words[0]),
            _ => bin_dir.join(self.binary()),
        }
    }

    /// The command line after the program, for pipeline `prefix`.
    pub fn argv(&self, prefix: &str) -> Vec<String> {
        let path = |p: &PathBuf| p.display().to_string();
        let mut argv: Vec<String> = match self {
            StageArgs::Recorder { .. } | StageArgs::Kinematics { .. } => vec![],
            StageArgs::Replay { file, .. } => vec![path(file)],
            StageArgs::ArmDriver { command, .. } => {
                command.as_ref().map_or_else(Vec::new, |w| w[1..].to_vec())
            }
            StageArgs::Mirror { .. } | StageArgs::Tracker => vec!["run".into()],
            StageArgs::Camera { .. } => vec!["sim".into()],
            StageArgs::Bridge(_) => vec![],
        };
        argv.extend(["--prefix".into(), prefix.into()]);
        let mut flag = |name: &str, value: String| argv.extend([format!("--{name}"), value]);
        match self {
            StageArgs::Recorder {
                out,
                no_drop,
                rig,
                attach,
                meta,
                live_view,
            } => {
                flag("out", path(out));
                flag("rig", path(rig));
                for a in attach {
                    flag("attach", path(a));
                }
                for (k, v) in meta {
                    flag("meta", format!("{k}={v}"));
                }
                if let Some(port) = live_view {
                    flag("live-view", port.to_string());
                }
                argv.push("--overwrite".into());
                if *no_drop {
                    argv.push("--no-drop".into());
                }
            }
            StageArgs::Mirror {
                rig,
                method,
                min_train,
                report,
                journal,
            } => {
                flag("rig", path(rig));
                flag("method", method.to_string());
                flag("min-train", min_train.to_string());
                flag("report", path(report));
                flag("journal", path(journal));
            }
            StageArgs::Tracker => {}
            StageArgs::Replay {
                kind,
                wait_subscribers,
                ..
            } => {
                flag("kind", kind.name().into());
                flag("pace", "lockstep".into());
                flag("wait-subscribers", wait_subscribers.to_string());
            }
            StageArgs::Camera { mirror, fps, look } => {
                flag("mirror", mirror.to_string());
                flag("fps", fps.to_string());
                flag("look", look.as_str().into());
            }
            StageArgs::ArmDriver {
                rig,
                command,
                move_ms,
                rate_hz,
            } => {
                flag("rig", path(rig));
                // The contract of a user's driver is --prefix and --rig only.
                if command.is_none() {
                    flag("move-ms", move_ms.to_string());
                    flag("rate-hz", rate_hz.to_string());
                }
            }
            StageArgs::Kinematics {
                rig,
                plan,
                dwell_ms,
                wait_subscribers,
                journal,
            } => {
                flag("rig", path(rig));
                flag("plan", path(plan));
                flag("dwell-ms", dwell_ms.to_string());
                flag("wait-subscribers", wait_subscribers.to_string());
                flag("journal", path(journal));
            }
            StageArgs::Bridge(b) => argv.extend(b.argv()),
        }
        argv
    }

    /// The stage's restart policy.
    pub fn restart_policy(&self) -> RestartPolicy {
        match self {
            StageArgs::Recorder { .. } => RestartPolicy::Optional,
            // It exits when the plan has ended and it has processed everything.
            StageArgs::Mirror { .. } => RestartPolicy::Finishes,
            StageArgs::Tracker | StageArgs::Bridge(_) => RestartPolicy::Service,
            StageArgs::Camera { .. } | StageArgs::Kinematics { .. } => RestartPolicy::Finishes,
            // It stops when the plan is finished, or is stopped with the run.
            StageArgs::ArmDriver { .. } => RestartPolicy::Finishes,
            // A failed replay started again publishes from the start; the
            // mirror stage drops what it has seen (stamps not moving on).
            StageArgs::Replay { .. } => RestartPolicy::Finishes,
        }
    }

    /// How long it may take to stop after SIGINT before it is killed: the
    /// recorder takes what is waiting and finishes its file; the bridge
    /// sends what is waiting.
    pub fn stop_grace(&self) -> Duration {
        match self {
            StageArgs::Recorder { .. } => Duration::from_secs(60),
            StageArgs::Bridge(_) => Duration::from_secs(10),
            _ => Duration::from_secs(3),
        }
    }
}

/// How many of `stages` subscribe to `topic`.
pub fn subscribers_of<'a>(
    stages: impl IntoIterator<Item = &'a StageArgs>,
    topic: TopicId,
) -> usize {
    stages
        .into_iter()
        .filter(|s| s.subscribes().contains(&topic))
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn only_a_live_runs_recorder_gives_way() {
        let recorder = |no_drop| StageArgs::Recorder {
            out: "out.mcap".into(),
            no_drop,
            rig: "r.toml".into(),
            attach: Vec::new(),
            meta: Vec::new(),
            live_view: None,
        };
        assert_eq!(recorder(false).niceness(), RECORDER_NICENESS);
        assert_eq!(recorder(true).niceness(), 0);
        assert_eq!(StageArgs::Tracker.niceness(), 0);
    }

    #[test]
    fn command_lines_follow_the_typed_arguments() {
        let mirror = StageArgs::Mirror {
            rig: "r.toml".into(),
            method: Method::Joint,
            min_train: 8,
            report: "out/report.json".into(),
            journal: "out/journal.mcap".into(),
        };
        assert_eq!(
            mirror.argv("p").join(" "),
            "run --prefix p --rig r.toml --method joint --min-train 8 --report out/report.json \
             --journal out/journal.mcap"
        );
        let camera = StageArgs::Camera {
            mirror: 2,
            fps: 30.0,
            look: Look::Realistic,
        };
        assert_eq!(
            camera.argv("p").join(" "),
            "sim --prefix p --mirror 2 --fps 30 --look realistic"
        );
        let sim_arm = StageArgs::ArmDriver {
            rig: "r.toml".into(),
            command: None,
            move_ms: 120,
            rate_hz: 250.0,
        };
        assert_eq!(sim_arm.binary(), "sim_arm");
        assert_eq!(
            sim_arm.argv("p").join(" "),
            "--prefix p --rig r.toml --move-ms 120 --rate-hz 250"
        );
        // A user's driver: its own words first, then only --prefix and --rig.
        let theirs = StageArgs::ArmDriver {
            rig: "r.toml".into(),
            command: Some(shell_words::split("py 'my driver.py' -v").unwrap()),
            move_ms: 120,
            rate_hz: 250.0,
        };
        assert_eq!(theirs.program(Path::new("bin")), PathBuf::from("py"));
        assert_eq!(
            theirs.argv("p"),
            ["my driver.py", "-v", "--prefix", "p", "--rig", "r.toml"]
        );
        assert_eq!(
            sim_arm.program(Path::new("bin")),
            PathBuf::from("bin/sim_arm")
        );
        let stages = [mirror, StageArgs::Tracker, camera, sim_arm];
        assert_eq!(subscribers_of(&stages, TopicId::JointState), 1);
        assert_eq!(subscribers_of(&stages, TopicId::JointPositions), 1);
        assert_eq!(subscribers_of(&stages, TopicId::PoseGoal), 2);
        assert_eq!(subscribers_of(&stages, TopicId::Frames), 1);
        assert_eq!(subscribers_of(&stages, TopicId::Samples), 0);
    }
}
