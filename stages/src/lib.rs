//! Every stage of the pipeline, declared once.
//!
//! A stage's module holds its arguments (the `clap::Args` struct its binary
//! parses), its ports (the topics it subscribes to and publishes, typed by
//! [`messages::topics`]) and how the launcher treats it (restart policy,
//! place on the path from frame to sample, side of a split run). The binary
//! parses that struct and opens its bus through [`Stage::bus`], which refuses
//! any port the declaration does not list; the launcher builds the same
//! struct and derives from the declaration the command line ([`argv`]),
//! readiness, what crosses in a split run, scheduling and restarts.
//!
//! This crate links no stage, so the launcher reads every declaration
//! without linking OpenCV.
//!
//! ```
//! use stages::{FixedPorts, StageArgs, tracker};
//! let args = tracker::Args { prefix: "demo".into(), ..Default::default() };
//! let stage = StageArgs::from(args);
//! assert_eq!(stage.binary(), "tracker_proc");
//! assert_eq!(stage.argv()[..3], ["run", "--prefix", "demo"]);
//! assert_eq!(tracker::Tracker::PORTS.publishes, [messages::topics::TopicId::Detections]);
//! ```

pub mod argv;
pub mod arm_driver;
pub mod bridge;
pub mod camera;
pub mod contract;
pub mod kinematics;
pub mod mirror;
pub mod recorder;
pub mod replay;
pub mod ros2;
pub mod sim_arm;
pub mod tracker;

use std::fmt::Debug;
use std::path::{Path, PathBuf};
use std::time::Duration;

use messages::topics::TopicId;
use runtime::{Bus, BusError, Ports};
use serde::{Deserialize, Serialize};

/// What a stage's exit means, and whether it is started again. (Which
/// stage's successful exit ends the run is the launcher's choice.)
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

/// Where a stage runs in a split run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Home {
    /// Always on this side.
    On(Side),
    /// On the robot unless the run's config offloads it to the workstation.
    Offloadable,
}

/// How long a stage may take to stop after SIGINT before it is killed,
/// unless its declaration says otherwise.
pub const STOP_GRACE: Duration = Duration::from_secs(3);

/// A stage, declared once: its binary, its arguments, its ports and how the
/// launcher treats it.
pub trait Stage {
    /// The arguments: the struct its binary parses (with `SUBCOMMAND`
    /// before them, if any).
    type Args: clap::Args + clap::FromArgMatches + Serialize + Clone + Debug + PartialEq;
    /// Its binary, and its name in logs and reports.
    const BINARY: &'static str;
    /// The subcommand of its binary that runs it as a stage, if any.
    const SUBCOMMAND: Option<&'static str> = None;
    /// Where it runs in a split run.
    const HOME: Home;
    /// For a stage every sample waits for, its rank above the base
    /// real-time priority. The tracker (and in a split run the bridge), the
    /// one stage on the path with much work a frame, is lowest, 1; the
    /// simulated camera above it, 2, as it stands for a camera, whose frame
    /// clock nothing on the computer delays (below the tracker, its moving
    /// frames waited behind the tracker's full scans, and above 60 fps some
    /// were made a period late); above the camera the stages that do little
    /// a message and that a sample waits for: the kinematics 3, the mirror
    /// stage 4 (above the tracker, so that one frame's sample never waits
    /// for the next frame's tracking), the arm driver and the cameras of a
    /// real robot 5 (a frame is paired once a joint state stamped after it
    /// has come). `None`: no sample waits for it.
    const SAMPLE_PATH_DEPTH: Option<u8>;
    /// Whether it publishes what it takes from the world by itself, with
    /// nothing on the bus asking (a camera, an arm driver): the
    /// launcher starts it only once every stage started before it
    /// listens, so that none of them misses its first messages (a tracker
    /// that saw frames a recorder did not could not be replayed bit for
    /// bit).
    const SOURCE: bool = false;
    /// Its restart policy.
    const RESTART: RestartPolicy;
    /// How long it may take to stop after SIGINT before it is killed.
    const STOP_GRACE: Duration = STOP_GRACE;

    /// The topics it subscribes to and publishes, given its arguments.
    fn ports(args: &Self::Args) -> Ports<'_>;

    /// The pipeline prefix in its arguments.
    fn prefix(args: &Self::Args) -> &str;

    /// Its bus: joins the pipeline as node [`Self::BINARY`] and refuses any
    /// port its declaration does not list.
    fn bus(args: &Self::Args) -> Result<Bus, BusError> {
        Ok(Bus::new(Self::prefix(args), Self::BINARY)?.declared(Self::ports(args)))
    }

    /// The program to run: its binary in `bin_dir`.
    fn program(_args: &Self::Args, bin_dir: &Path) -> PathBuf {
        bin_dir.join(Self::BINARY)
    }

    /// The words of its command line between the program and the
    /// arguments: the subcommand, if any.
    fn leading_words(_args: &Self::Args) -> Vec<String> {
        Self::SUBCOMMAND.into_iter().map(String::from).collect()
    }

    /// Its command line after the program: the leading words, then the
    /// arguments ([`argv::of`]).
    fn argv(args: &Self::Args) -> Vec<String> {
        let mut words = Self::leading_words(args);
        words.extend(argv::of(args));
        words
    }

    /// Its scheduling niceness (0: the launcher's own).
    fn niceness(_args: &Self::Args) -> i32 {
        0
    }

    /// Arguments away from their defaults where the launcher sets them:
    /// what the command-line round trip is checked on.
    fn example() -> Self::Args;

    /// Whether `parsed`, the command line for `args` parsed back by the
    /// binary's parser, is `args` again: equality, unless the arguments
    /// hold what is not an argument.
    fn parsed_again(args: &Self::Args, parsed: &Self::Args) -> bool {
        args == parsed
    }
}

/// Joins `prefix` as stage `S` with ports that do not depend on its
/// arguments (`S::PORTS`): for library loops that take a prefix.
pub fn bus_of<S: FixedPorts>(prefix: &str) -> Result<Bus, BusError> {
    Ok(Bus::new(prefix, S::BINARY)?.declared(S::PORTS))
}

/// A stage whose ports do not depend on its arguments.
pub trait FixedPorts: Stage {
    /// Its ports.
    const PORTS: Ports<'static>;
}

macro_rules! stage_table {
    ($($(#[$doc:meta])* $variant:ident($stage:ty)),* $(,)?) => {
        /// A stage of a run with its typed arguments: one entry per stage.
        #[derive(Debug, Clone, PartialEq)]
        pub enum StageArgs {
            $($(#[$doc])* $variant(<$stage as Stage>::Args),)*
        }

        $(impl From<<$stage as Stage>::Args> for StageArgs {
            fn from(args: <$stage as Stage>::Args) -> Self {
                StageArgs::$variant(args)
            }
        })*

        impl StageArgs {
            /// Its name in logs and reports: [`Stage::BINARY`].
            pub fn binary(&self) -> &'static str {
                match self { $(StageArgs::$variant(_) => <$stage>::BINARY,)* }
            }
            /// [`Stage::ports`].
            pub fn ports(&self) -> Ports<'_> {
                match self { $(StageArgs::$variant(a) => <$stage>::ports(a),)* }
            }
            /// [`Stage::program`].
            pub fn program(&self, bin_dir: &Path) -> PathBuf {
                match self { $(StageArgs::$variant(a) => <$stage>::program(a, bin_dir),)* }
            }
            /// [`Stage::argv`].
            pub fn argv(&self) -> Vec<String> {
                match self { $(StageArgs::$variant(a) => <$stage>::argv(a),)* }
            }
            /// [`Stage::HOME`].
            pub fn home(&self) -> Home {
                match self { $(StageArgs::$variant(_) => <$stage>::HOME,)* }
            }
            /// [`Stage::SAMPLE_PATH_DEPTH`].
            pub fn sample_path_depth(&self) -> Option<u8> {
                match self { $(StageArgs::$variant(_) => <$stage>::SAMPLE_PATH_DEPTH,)* }
            }
            /// [`Stage::SOURCE`].
            pub fn is_source(&self) -> bool {
                match self { $(StageArgs::$variant(_) => <$stage>::SOURCE,)* }
            }
            /// [`Stage::RESTART`].
            pub fn restart_policy(&self) -> RestartPolicy {
                match self { $(StageArgs::$variant(_) => <$stage>::RESTART,)* }
            }
            /// [`Stage::STOP_GRACE`].
            pub fn stop_grace(&self) -> Duration {
                match self { $(StageArgs::$variant(_) => <$stage>::STOP_GRACE,)* }
            }
            /// [`Stage::niceness`].
            pub fn niceness(&self) -> i32 {
                match self { $(StageArgs::$variant(a) => <$stage>::niceness(a),)* }
            }
        }

        impl StageArgs {
            /// Every stage's [`Stage::example`].
            pub fn examples() -> Vec<StageArgs> {
                vec![$(<$stage>::example().into()),*]
            }

            /// Checks that this stage's command line, parsed back by its
            /// binary's parser, gives its arguments again ([`argv`]).
            pub fn check_argv_round_trip(&self) -> Result<(), argv::RoundTripError> {
                match self { $(StageArgs::$variant(a) => argv::round_trip::<$stage>(a),)* }
            }
        }
    };
}

stage_table! {
    /// `recorder`: every topic into one MCAP file.
    Recorder(recorder::Recorder),
    /// `mirror_proc run`: pairing, calibration, predictions.
    Mirror(mirror::Mirror),
    /// `tracker_proc run`: ArUco detection.
    Tracker(tracker::Tracker),
    /// `camera_proc sim`: the simulated head.
    Camera(camera::Camera),
    /// `replay`: a recording's messages back onto the topics.
    Replay(replay::Replay),
    /// `sim_arm`: the simulated arm driver.
    SimArm(sim_arm::SimArm),
    /// A real arm's driver: the user's command.
    ArmDriver(arm_driver::ArmDriver),
    /// `kinematics_proc`: the pose plan, through the arm driver.
    Kinematics(kinematics::Kinematics),
    /// `bridge`: this side's topics to the other host of a split run.
    Bridge(bridge::Bridge),
    /// `ros2_proc arm`: a ROS 2 robot's arm as the arm driver.
    Ros2Arm(ros2::Ros2Arm),
    /// `ros2_proc tf`: calibrations and located objects out to ROS 2.
    Ros2Tf(ros2::Ros2Tf),
    /// `ros2_proc camera`: a ROS 2 stereo camera as the camera stage.
    Ros2Camera(ros2::Ros2Camera),
}

impl StageArgs {
    /// The topics it subscribes to.
    pub fn subscribes(&self) -> &[TopicId] {
        self.ports().subscribes
    }

    /// The topics it publishes.
    pub fn publishes(&self) -> &[TopicId] {
        self.ports().publishes
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

/// Parses a topic's name (a clap value parser).
pub fn parse_topic(name: &str) -> Result<TopicId, UnknownTopic> {
    TopicId::from_name(name).ok_or_else(|| UnknownTopic {
        name: name.to_string(),
    })
}

/// A name [`parse_topic`] does not know; it says which topics there are.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("no topic {name:?} (topics: {})", known_topics())]
pub struct UnknownTopic {
    /// The name given.
    pub name: String,
}

/// The names of every topic, comma separated.
fn known_topics() -> String {
    let known: Vec<_> = TopicId::ALL.iter().map(|t| t.name()).collect();
    known.join(", ")
}

/// Writes topics by name (for [`argv::of`]).
fn serialize_topics<S: serde::Serializer>(
    topics: &[TopicId],
    serializer: S,
) -> Result<S::Ok, S::Error> {
    serializer.collect_seq(topics.iter().map(|t| t.name()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_users_driver_is_its_own_program_given_only_the_contract() {
        let driver = StageArgs::examples()
            .into_iter()
            .find(|s| matches!(s, StageArgs::ArmDriver(_)))
            .unwrap();
        assert_eq!(driver.program(Path::new("bin")), PathBuf::from("py"));
        assert_eq!(
            driver.argv(),
            ["my driver.py", "-v", "--prefix", "p", "--rig", "r.toml"]
        );
        assert_eq!(driver.ports(), sim_arm::DRIVER_PORTS);
    }

    /// A stage's bus opens the ports its declaration lists and refuses
    /// any other, naming the stage and the topic.
    #[test]
    fn a_stages_bus_refuses_an_undeclared_port() {
        use messages::topics;
        let prefix = format!("stages_test{}", std::process::id());
        let bus = bus_of::<tracker::Tracker>(&prefix).unwrap();
        bus.frame_subscriber::<topics::Frames>().unwrap();
        bus.publisher::<topics::Detections>().unwrap();
        let err = bus.publisher::<topics::Samples>().err().unwrap();
        assert!(
            matches!(
                err,
                BusError::Undeclared {
                    direction: "publisher",
                    topic: "samples",
                    ..
                }
            ),
            "{err}"
        );
        assert_eq!(
            err.to_string(),
            "tracker_proc opens a publisher of `samples`, which its declaration does not list"
        );
        assert!(matches!(
            bus.subscriber::<topics::Detections>(),
            Err(BusError::Undeclared { .. })
        ));
    }

    #[test]
    fn only_a_live_runs_recorder_gives_way() {
        let live = StageArgs::from(recorder::Args::default());
        let replaying = StageArgs::from(recorder::Args {
            no_drop: true,
            ..Default::default()
        });
        assert_eq!(live.niceness(), recorder::NICENESS);
        assert_eq!(replaying.niceness(), 0);
        assert_eq!(StageArgs::from(tracker::Args::default()).niceness(), 0);
    }

    #[test]
    fn subscribers_are_counted_from_the_declarations() {
        let stages = StageArgs::examples();
        // The recorder subscribes to everything; the mirror stage and the
        // bridge (which sends them) to joint states; the camera and the
        // three arm drivers (simulated, a user's, a ROS 2 robot's) to pose
        // goals.
        assert_eq!(subscribers_of(&stages, TopicId::JointState), 3);
        assert_eq!(subscribers_of(&stages, TopicId::PoseGoal), 5);
        assert_eq!(subscribers_of(&stages, TopicId::Frames), 3);
        assert_eq!(subscribers_of(&stages, TopicId::Samples), 1);
    }

    /// The launcher's command line for a stage is the binary's: the tracker
    /// and the mirror stage behind their `run`, the camera behind `sim`.
    #[test]
    fn command_lines_follow_the_typed_arguments() {
        let argv = |s: &StageArgs| s.argv().join(" ");
        let stages = StageArgs::examples();
        assert_eq!(
            argv(&stages[1]),
            "run --prefix p --rig r.toml --method joint --min-train 12 --settle-ms 30 \
             --report out/report.json --journal out/journal.mcap --no-drift-watch"
        );
        assert_eq!(
            argv(&stages[3]),
            "sim --prefix p --mirror 2 --fps 29.97 --tail-frames 5 --look clean --mjpeg 80 \
             --change 10004:mirror:1:-2.5 --change 30002:camera:0:0.3:roll"
        );
        assert_eq!(
            argv(&stages[4]),
            "a.mcap --prefix p --kind detections --topics joint_state --topics detections \
             --pace 2.5x --start 0.0 --wait-subscribers 3 --wait-timeout 30.0"
        );
    }
}
