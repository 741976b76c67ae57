//! `replay`: a recording's messages back onto the topics, in lockstep with
//! the slowest subscriber.

use std::path::PathBuf;

use messages::topics::TopicId;
use runtime::Ports;
use serde::{Serialize, Serializer};

use crate::{Home, RestartPolicy, Side, Stage};

/// What a replay publishes, named for the stages it lets re-run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Kind {
    /// Frames and joint states: the tracker and the mirror stage re-run.
    Frames,
    /// Detections and joint states: the mirror stage re-runs.
    Detections,
    /// Every recorded topic.
    All,
}

impl Kind {
    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Frames => "frames",
            Kind::Detections => "detections",
            Kind::All => "all",
        }
    }

    /// The topics it publishes.
    pub fn topics(self) -> &'static [TopicId] {
        match self {
            Kind::Frames => &[TopicId::Frames, TopicId::JointState],
            Kind::Detections => &[TopicId::Detections, TopicId::JointState],
            Kind::All => &TopicId::ALL,
        }
    }
}

/// How fast to replay.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// As recorded (log-time gaps kept).
    Original,
    /// Log-time gaps divided by this factor (2 = twice as fast).
    Scaled(f64),
    /// As fast as the slowest consumer takes the messages.
    Lockstep,
}

/// A pace that is none of original, lockstep or a positive factor.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("`{0}`: expected original, lockstep or a speed factor such as 2x")]
pub struct BadPace(pub String);

impl std::str::FromStr for Pace {
    type Err = BadPace;
    fn from_str(s: &str) -> Result<Self, BadPace> {
        match s {
            "original" => Ok(Pace::Original),
            "lockstep" => Ok(Pace::Lockstep),
            _ => match s.strip_suffix('x').unwrap_or(s).parse::<f64>() {
                Ok(f) if f.is_finite() && f > 0.0 => Ok(Pace::Scaled(f)),
                _ => Err(BadPace(s.to_string())),
            },
        }
    }
}

impl std::fmt::Display for Pace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Pace::Original => f.write_str("original"),
            Pace::Lockstep => f.write_str("lockstep"),
            Pace::Scaled(factor) => write!(f, "{factor}x"),
        }
    }
}

impl Serialize for Pace {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

/// Replaying a recording.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
pub struct Args {
    /// The MCAP recording.
    #[arg(required = true)]
    pub file: Option<PathBuf>,
    /// Service prefix to publish on (use a fresh one, not a live pipeline's).
    #[arg(long, required = true)]
    pub prefix: Option<String>,
    /// What to publish: `frames` (frames and joint states), `detections`
    /// (detections and joint states), or `all` (every recorded topic).
    #[arg(long, value_enum, default_value_t = Kind::Frames)]
    pub kind: Kind,
    /// Publish exactly these topics instead (comma separated), e.g. joint_state,detections.
    #[arg(long, value_delimiter = ',', value_parser = crate::parse_topic)]
    #[serde(serialize_with = "serialize_some_topics")]
    pub topics: Option<Vec<TopicId>>,
    /// original, lockstep (as fast as the slowest consumer takes them), or a factor such as 2x.
    #[arg(long, default_value = "lockstep")]
    pub pace: Pace,
    /// Start this many seconds after the first message.
    #[arg(long, default_value_t = 0.0)]
    pub start: f64,
    /// Wait until each replayed topic has this many subscribers.
    #[arg(long, default_value_t = 1)]
    pub wait_subscribers: usize,
    /// How long to wait for them, s.
    #[arg(long, default_value_t = 30.0)]
    pub wait_timeout: f64,
    /// Print the statistics as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

impl Args {
    /// A replay of `file` on `prefix` with the defaults.
    pub fn new(file: impl Into<PathBuf>, prefix: impl Into<String>) -> Self {
        Self {
            file: Some(file.into()),
            prefix: Some(prefix.into()),
            kind: Kind::Frames,
            topics: None,
            pace: Pace::Lockstep,
            start: 0.0,
            wait_subscribers: 1,
            wait_timeout: 30.0,
            json: false,
        }
    }

    /// The topics it publishes: `--topics`, or those of its kind.
    pub fn published(&self) -> &[TopicId] {
        self.topics.as_deref().unwrap_or(self.kind.topics())
    }
}

fn serialize_some_topics<S: Serializer>(
    topics: &Option<Vec<TopicId>>,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    match topics {
        Some(topics) => crate::serialize_topics(topics, serializer),
        None => serializer.serialize_none(),
    }
}

/// The replay's declaration.
pub struct Replay;

impl Stage for Replay {
    type Args = Args;
    const BINARY: &'static str = "replay";
    const HOME: Home = Home::On(Side::Workstation);
    const SAMPLE_PATH_DEPTH: Option<u8> = None;
    /// A failed replay started again publishes from the start; the mirror
    /// stage drops what it has seen (stamps not moving on).
    const RESTART: RestartPolicy = RestartPolicy::Finishes;

    fn ports(args: &Args) -> Ports<'_> {
        Ports {
            subscribes: &[],
            publishes: args.published(),
        }
    }

    fn prefix(args: &Args) -> &str {
        args.prefix.as_deref().unwrap_or_default()
    }

    fn example() -> Args {
        Args {
            kind: Kind::Detections,
            topics: Some(vec![TopicId::JointState, TopicId::Detections]),
            pace: Pace::Scaled(2.5),
            wait_subscribers: 3,
            ..Args::new("a.mcap", "p")
        }
    }
}
