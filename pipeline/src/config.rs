//! The run's settings: `pipeline.toml`, with the command line's overrides.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use mirror_proc::calibrate::{Estimate, Method};
use serde::{Deserialize, Serialize};

use crate::split::SplitConfig;

/// The robot and scene a run simulates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// The Nico-like head and arm in front of three mirror placements.
    Nico,
}

/// Where the frames come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Source {
    /// The simulated head renders them.
    Sim,
}

/// What the simulated camera's images look like (`camera_proc sim --look`).
pub use stages::camera::LookName as Look;

/// The run's settings.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Robot and scene.
    pub preset: Preset,
    /// Mirror placements to run, in order.
    pub mirrors: Vec<usize>,
    /// Calibration poses per placement.
    pub train_poses: usize,
    /// Test poses seen in the mirror, per placement.
    pub test_poses: usize,
    /// Test poses seen directly, per placement.
    pub direct_poses: usize,
    /// Calibration method.
    pub method: Method,
    /// Frame source.
    pub source: Source,
    /// Camera frame rate, Hz.
    pub fps: f64,
    /// What the simulated camera's images look like (default `realistic`).
    #[serde(default)]
    pub look: Look,
    /// Move time between poses of the simulated arm (`sim_arm`), ms.
    pub move_ms: u64,
    /// Joint-position rate of the simulated arm (`sim_arm`), Hz. The mirror
    /// stage pairs a frame once a joint state stamped after it has come, so
    /// the driver's period bounds the frame-to-sample latency.
    #[serde(default = "default_arm_rate_hz")]
    pub arm_rate_hz: f64,
    /// Dwell time at each pose, ms.
    pub dwell_ms: u64,
    /// Seed of the simulated poses.
    pub seed: u64,
    /// Training samples before the first calibration.
    pub min_train: usize,
    /// The arm driver's command (`--prefix P --rig R` are appended);
    /// absent: the built-in simulated arm, `sim_arm`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm_driver: Option<String>,
    /// A ROS 2 robot on rmw_zenoh as the arm driver (`[ros2]`, or
    /// `pipeline --ros2 ENDPOINT`): `ros2_proc arm`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ros2: Option<Ros2Config>,
    /// A run split across a robot and a workstation (`pipeline --side`):
    /// where the tracker runs and how frames cross.
    #[serde(default)]
    pub split: SplitConfig,
    /// Base `SCHED_FIFO` priority (1 to 97) of the stages every sample
    /// waits for in a live run, each
    /// [`stages::StageArgs::sample_path_depth`] above it; 0: the
    /// launcher's own scheduling. Needs root, `CAP_SYS_NICE` or an rtprio limit
    /// (`ulimit -r`); without, the launcher says so and runs them normally.
    #[serde(default = "default_realtime_priority")]
    pub realtime_priority: u8,
    /// What to estimate of the arm across the placements when the run
    /// ends (`base`, `tool` or `base,tool`; `--estimate`): one combined
    /// calibration in `report.json`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub estimate: Option<String>,
    /// How far the rig handed to the stages is from the simulated robot,
    /// as a rig measured by hand would be (`[rig_error]`); the simulator
    /// and the truth in the report keep the true one.
    #[serde(default, skip_serializing_if = "RigError::is_zero")]
    pub rig_error: RigError,
    /// Changes of the simulated world during the run (`[[event]]`): see
    /// [`crate::events`].
    #[serde(default, rename = "event", skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<crate::events::Event>,
}

/// Errors put into the rig the stages get (`[rig_error]`), in fixed
/// directions: the base shifted along `(1, 2, -1)` of its frame and turned
/// about `(1, -1, 1)`, the tool shifted along `(1, 0, 1)`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigError {
    /// The base's shift, mm.
    #[serde(default)]
    pub base_mm: f64,
    /// The base's turn, degrees.
    #[serde(default)]
    pub base_deg: f64,
    /// The tool point's shift, mm.
    #[serde(default)]
    pub tool_mm: f64,
}

impl RigError {
    fn is_zero(&self) -> bool {
        *self == RigError::default()
    }

    /// `rig` with these errors in its arm.
    pub fn apply(&self, rig: &geometry::Rig) -> geometry::Rig {
        use nalgebra::{Isometry3, Vector3};
        let mut rig = rig.clone();
        if let Some(arm) = rig.arm.as_mut() {
            let shift = Vector3::new(1.0, 2.0, -1.0).normalize() * self.base_mm;
            let turn = Vector3::new(1.0, -1.0, 1.0).normalize() * self.base_deg.to_radians();
            arm.world_from_base *= Isometry3::new(shift, turn);
            arm.tool += Vector3::new(1.0, 0.0, 1.0).normalize() * self.tool_mm;
        }
        rig
    }
}

/// The ROS 2 graph the robot is on (`[ros2]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ros2Config {
    /// Zenoh endpoint of the robot's router (`rmw_zenohd`), e.g.
    /// `tcp/robot.local:7447`.
    pub endpoint: String,
    /// ROS domain id; absent: this environment's `ROS_DOMAIN_ID`, else 0
    /// (resolved when the config is loaded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub domain: Option<u32>,
    /// Our node's namespace.
    #[serde(default = "default_namespace")]
    pub namespace: String,
    /// The robot's joint-state topic.
    #[serde(default = "default_joint_states")]
    pub joint_states: String,
    /// The trajectory controller's topic.
    #[serde(default = "default_trajectory")]
    pub trajectory: String,
    /// Whether each calibration goes out on `/tf_static` and each located
    /// object on `located_topic` (`ros2_proc tf`).
    #[serde(default = "default_true")]
    pub tf: bool,
    /// Topic of the located objects (`geometry_msgs/PointStamped`).
    #[serde(default = "default_located")]
    pub located_topic: String,
    /// For a `tls/` endpoint: the CA the router's certificate is signed by
    /// (relative to the config file, as the other two).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tls_ca: Option<PathBuf>,
    /// For a router that requires client certificates: ours.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tls_cert: Option<PathBuf>,
    /// The key of `tls_cert`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tls_key: Option<PathBuf>,
}

impl Ros2Config {
    /// The graph at `endpoint` with every other setting at its default.
    pub fn at(endpoint: &str) -> Self {
        Ros2Config {
            endpoint: endpoint.into(),
            domain: None,
            namespace: default_namespace(),
            joint_states: default_joint_states(),
            trajectory: default_trajectory(),
            tf: true,
            located_topic: default_located(),
            tls_ca: None,
            tls_cert: None,
            tls_key: None,
        }
    }

    /// The graph, as `ros2_proc` takes it.
    pub fn graph(&self) -> stages::ros2::Graph {
        stages::ros2::Graph {
            endpoint: self.endpoint.clone(),
            domain: self.domain.unwrap_or(0),
            namespace: self.namespace.clone(),
            tls_ca: self.tls_ca.clone(),
            tls_cert: self.tls_cert.clone(),
            tls_key: self.tls_key.clone(),
        }
    }

    /// The domain: the config's, else `ROS_DOMAIN_ID`, else 0.
    fn resolve_domain(&self) -> Result<u32> {
        if let Some(d) = self.domain {
            return Ok(d);
        }
        match std::env::var("ROS_DOMAIN_ID") {
            Ok(v) if !v.trim().is_empty() => v
                .trim()
                .parse()
                .with_context(|| format!("ROS_DOMAIN_ID={v:?} is not a domain id")),
            _ => Ok(0),
        }
    }
}

fn default_namespace() -> String {
    "/".into()
}

fn default_joint_states() -> String {
    "/joint_states".into()
}

fn default_true() -> bool {
    true
}

fn default_located() -> String {
    "/mirror/located".into()
}

fn default_trajectory() -> String {
    "/joint_trajectory_controller/joint_trajectory".into()
}

/// `sim_arm`'s joint-position rate unless the config says: that of a
/// typical arm controller's state stream (125 Hz to 1 kHz).
fn default_arm_rate_hz() -> f64 {
    250.0
}

/// Real-time priority unless the config says: above the kernel's threaded
/// interrupts' default of 50 would starve them; low in the range is enough
/// to run before every normally scheduled process.
fn default_realtime_priority() -> u8 {
    10
}

/// What the command line may override.
#[derive(Debug, Clone, Default)]
pub struct Overrides {
    /// Mirror placements.
    pub mirrors: Option<Vec<usize>>,
    /// Calibration poses per placement.
    pub train_poses: Option<usize>,
    /// Calibration method.
    pub method: Option<Method>,
    /// Camera frame rate, Hz.
    pub fps: Option<f64>,
    pub arm_driver: Option<String>,
    /// The ROS 2 robot's endpoint (`--ros2`).
    pub ros2: Option<String>,
    /// Real-time priority of the stages between frame and sample.
    pub realtime_priority: Option<u8>,
    /// What to estimate of the arm across the placements (`--estimate`).
    pub estimate: Option<String>,
}

impl Config {
    /// Reads `path`, applies `overrides` and checks the result against the
    /// simulated scene; errors name the file and the key.
    pub fn load(path: &Path, overrides: Overrides) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        let mut config: Config = toml::from_str(&text)
            .map_err(|e| anyhow::anyhow!("{}: {}", path.display(), one_line(e.message())))?;
        let Overrides {
            mirrors,
            train_poses,
            method,
            fps,
            arm_driver,
            ros2,
            realtime_priority,
            estimate,
        } = overrides;
        config.estimate = estimate.or(config.estimate);
        config.mirrors = mirrors.unwrap_or(config.mirrors);
        config.train_poses = train_poses.unwrap_or(config.train_poses);
        config.method = method.unwrap_or(config.method);
        config.fps = fps.unwrap_or(config.fps);
        config.arm_driver = arm_driver.or(config.arm_driver);
        if let Some(endpoint) = ros2 {
            match &mut config.ros2 {
                Some(r) => r.endpoint = endpoint,
                None => config.ros2 = Some(Ros2Config::at(&endpoint)),
            }
        }
        if config.ros2.is_some() && config.arm_driver.is_some() {
            bail!(
                "{}: both arm_driver and ros2 name the arm driver; give one",
                path.display()
            );
        }
        if let Some(r) = &mut config.ros2 {
            r.domain = Some(r.resolve_domain()?);
            if r.tls_cert.is_some() != r.tls_key.is_some() {
                bail!(
                    "{}: keys ros2.tls_cert and ros2.tls_key: give both or neither",
                    path.display()
                );
            }
            if r.tls_cert.is_some() && r.tls_ca.is_none() {
                bail!("{}: key ros2.tls_cert needs ros2.tls_ca", path.display());
            }
        }
        config.realtime_priority = realtime_priority.unwrap_or(config.realtime_priority);
        if let Some(command) = &config.arm_driver {
            let words = shell_words::split(command)
                .map_err(|e| anyhow::anyhow!("arm_driver: {command:?}: {e}"))?;
            if words.is_empty() {
                bail!("arm_driver: the command is empty");
            }
        }
        let placements = match config.preset {
            Preset::Nico => geometry::sim::nico_scene().mirrors.len(),
        };
        if let Some(bad) = config.mirrors.iter().find(|m| **m >= placements) {
            bail!(
                "{}: key mirrors: placement {bad} does not exist (0..={})",
                path.display(),
                placements - 1
            );
        }
        crate::events::check(path, &config.events, placements)?;
        if !(config.fps > 0.0 && config.fps <= 1000.0) {
            bail!(
                "{}: key fps: {} is not in (0, 1000]",
                path.display(),
                config.fps
            );
        }
        if let Some(ms) = config.split.lease_ms
            && !(100..=600_000).contains(&ms)
        {
            bail!(
                "{}: key split.lease_ms: {ms} is not within 100 ms to 10 min",
                path.display()
            );
        }
        // Files named in the config are relative to it.
        let beside_config = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = path.parent().unwrap_or(Path::new("")).join(&*p);
            }
        };
        config.split.certs.iter_mut().for_each(beside_config);
        if let Some(r) = &mut config.ros2 {
            [&mut r.tls_ca, &mut r.tls_cert, &mut r.tls_key]
                .into_iter()
                .flatten()
                .for_each(beside_config);
        }
        if !(config.arm_rate_hz > 0.0 && config.arm_rate_hz <= 1000.0) {
            bail!(
                "{}: key arm_rate_hz: {} is not in (0, 1000]",
                path.display(),
                config.arm_rate_hz
            );
        }
        if config.realtime_priority > 97 {
            bail!(
                "{}: key realtime_priority: {} is not in 0 to 97",
                path.display(),
                config.realtime_priority
            );
        }
        if let Some(list) = &config.estimate {
            let estimate: Estimate = list
                .parse()
                .map_err(|e| anyhow::anyhow!("{}: key estimate: {e}", path.display()))?;
            if estimate.any() && config.method == Method::Paper {
                bail!(
                    "{}: key estimate: the paper's method has no arm model to correct; use method joint or joint+kinematics",
                    path.display()
                );
            }
        }
        let e = &config.rig_error;
        if ![e.base_mm, e.base_deg, e.tool_mm]
            .iter()
            .all(|v| v.is_finite() && *v >= 0.0)
        {
            bail!(
                "{}: table rig_error: base_mm, base_deg and tool_mm must be finite and not negative",
                path.display()
            );
        }
        Ok(config)
    }

    /// What to estimate of the arm across the placements.
    pub fn estimate(&self) -> Estimate {
        self.estimate
            .as_deref()
            .and_then(|e| e.parse().ok())
            .unwrap_or_default()
    }
}

fn one_line(text: &str) -> String {
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn load(text: &str, overrides: Overrides) -> Result<Config> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pipeline.toml");
        std::fs::write(&path, text).unwrap();
        Config::load(&path, overrides)
    }

    const GOOD: &str = "preset = \"nico\"\nmirrors = [0, 2]\ntrain_poses = 30\ntest_poses = 20\n\
        direct_poses = 10\nmethod = \"joint+kinematics\"\nsource = \"sim\"\nfps = 30.0\n\
        move_ms = 120\ndwell_ms = 180\nseed = 1\nmin_train = 8\n";

    #[test]
    fn the_repository_config_loads_and_overrides_apply() {
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml");
        let config = Config::load(&shipped, Overrides::default()).unwrap();
        assert_eq!(config.method, Method::JointKinematics);
        let config = load(
            GOOD,
            Overrides {
                mirrors: Some(vec![1]),
                method: Some(Method::Paper),
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!((config.mirrors, config.method), (vec![1], Method::Paper));
        let config = load(
            &format!("{GOOD}realtime_priority = 20\n"),
            Overrides {
                realtime_priority: Some(0),
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(config.realtime_priority, 0, "the command line wins");
    }

    #[test]
    fn a_ros2_robot_is_the_arm_from_the_table_or_the_command_line() {
        let config = load(
            &format!("{GOOD}[ros2]\nendpoint = \"tcp/robot:7447\"\ndomain = 3\n"),
            Overrides::default(),
        )
        .unwrap();
        let ros2 = config.ros2.unwrap();
        assert_eq!(ros2.graph().domain, 3);
        assert_eq!(ros2.joint_states, "/joint_states");
        assert!(ros2.tf);
        let config = load(
            GOOD,
            Overrides {
                ros2: Some("tcp/10.0.0.2:7447".into()),
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(config.ros2.unwrap().endpoint, "tcp/10.0.0.2:7447");
        let e = load(
            &format!("{GOOD}arm_driver = \"my_driver\"\n"),
            Overrides {
                ros2: Some("tcp/robot:7447".into()),
                ..Default::default()
            },
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("both arm_driver and ros2"), "{e}");
        let e = load(
            &format!("{GOOD}[ros2]\nendpoint = \"tcp/r:7447\"\ntopic = \"/x\"\n"),
            Overrides::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("unknown field `topic`"), "{e}");
    }

    #[test]
    fn events_are_checked_and_the_plan_extended_after_them() {
        let events = "[[event]]\nat_pose = 35\nmirror = { tilt_deg = 1.0, shift_mm = 5.0 }\n\n\
            [[event]]\nat_pose = 70\ncamera = { name = \"left\", rotate_deg = 0.3 }\n";
        let config = load(&format!("{GOOD}{events}"), Overrides::default()).unwrap();
        assert_eq!(config.events.len(), 2);
        let (_, plan) = crate::run::plan_for(&config, 0).unwrap();
        let after = &plan[70..];
        let count = |role| after.iter().filter(|p| p.role == role).count();
        assert!(count(geometry::Role::Train) >= crate::events::TRAIN_AFTER);
        assert!(count(geometry::Role::Direct) >= crate::events::DIRECT_AFTER);
        let ids: std::collections::BTreeSet<u64> = plan.iter().map(|p| p.pose).collect();
        assert_eq!(ids.len(), plan.len(), "every pose id once");
        let changes =
            crate::events::changes(&crate::events::of_placement(&config.events, 0), &plan);
        assert_eq!(
            changes.iter().map(|c| c.pose).collect::<Vec<_>>(),
            [plan[35].pose, plan[70].pose]
        );
        for (bad, why) in [
            ("[[event]]\nat_pose = 5\n", "give one of"),
            (
                "[[event]]\nat_pose = 5\ncamera = { name = \"middle\", rotate_deg = 1.0 }\n",
                "\"middle\" is not one of",
            ),
            (
                "[[event]]\nat_pose = 9\nmirror = {}\n[[event]]\nat_pose = 5\nmirror = {}\n",
                "plan order",
            ),
            ("[[event]]\nat_pose = 0\nmirror = {}\n", "at_pose 0"),
            (
                "[[event]]\nat_pose = 5\nplacement = 3\nmirror = {}\n",
                "placement 3 does not exist",
            ),
            (
                "[[event]]\nat_pose = 5\nmirror = { tilt = 1.0 }\n",
                "unknown field `tilt`",
            ),
        ] {
            let e = load(&format!("{GOOD}{bad}"), Overrides::default())
                .unwrap_err()
                .to_string();
            assert!(e.contains(why) && !e.contains('\n'), "{bad}: {e}");
        }
    }

    #[test]
    fn bad_values_are_named_with_their_key() {
        let e = load(
            &GOOD.replace("joint+kinematics", "best"),
            Overrides::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("unknown variant `best`") && e.contains("joint+kinematics"),
            "{e}"
        );
        let e = load(&GOOD.replace("\"sim\"", "\"device\""), Overrides::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown variant `device`"), "{e}");
        let e = load(&GOOD.replace("[0, 2]", "[0, 3]"), Overrides::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.ends_with("key mirrors: placement 3 does not exist (0..=2)"),
            "{e}"
        );
        assert!(!e.contains('\n'));
        let e = load(&format!("{GOOD}arm_rate_hz = 0\n"), Overrides::default())
            .unwrap_err()
            .to_string();
        assert!(e.ends_with("key arm_rate_hz: 0 is not in (0, 1000]"), "{e}");
        let config = load(GOOD, Overrides::default()).unwrap();
        assert_eq!(config.arm_rate_hz, 250.0, "the default");
        assert_eq!(config.realtime_priority, 10, "the default");
        let e = load(
            &format!("{GOOD}realtime_priority = 100\n"),
            Overrides::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.ends_with("key realtime_priority: 100 is not in 0 to 97"),
            "{e}"
        );
        assert_eq!(
            config.split.tracker,
            crate::split::Side::Robot,
            "the default"
        );
        let e = load(
            &format!("{GOOD}[split]\ntracker = \"cloud\"\n"),
            Overrides::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("unknown variant `cloud`") && e.contains("workstation"),
            "{e}"
        );
        let e = load(
            &format!("{GOOD}[split]\nlease_ms = 5\n"),
            Overrides::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.ends_with("key split.lease_ms: 5 is not within 100 ms to 10 min"),
            "{e}"
        );
    }
}
