//! One placement's run: write its rig and plan, start the stages from
//! their specs, follow the progress, stop them, and compare the result with
//! the simulator's truth.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use formats::plan::PlannedPose;
use geometry::Role;
use geometry::sim::{Counts, Dataset, generate, nico_noise, nico_scene};
use messages::CalibrationMsg;
use messages::topics::{self, TopicId};
use mirror_proc::live::LiveReport;
use runtime::Bus;

use crate::config::Config;
use crate::report::{PlacementResult, TruthErrors};
use crate::split::{Link, Side, crossing, side_of};
use crate::supervise::{Launch, Progress, Supervisor, see, wait_ready};
use stages::{StageArgs, subscribers_of};

/// How long the consumers may take to subscribe.
const READY_WITHIN: Duration = Duration::from_secs(30);

/// How long one side of a split run waits for the other (whose stages
/// subscribe through the bridge): the other host may be started later.
const OTHER_SIDE_WITHIN: Duration = Duration::from_secs(600);

/// Waits for the stages started so far to listen, and fails the placement
/// if they do not in time.
struct Readiness {
    side: Option<Side>,
    mirror: usize,
    /// Whether a wait has passed: on a split run, the other side was up
    /// for it (this side's bridge subscribes once it is on the link), and
    /// later waits are for this side's stages only.
    passed: bool,
}

impl Readiness {
    /// Returns once every started stage has subscribed to what its spec
    /// says (the caller stops them if not). A split run's first wait may
    /// need the other side, which may be started much later: it says so
    /// and is long.
    fn wait(
        &mut self,
        run: &Run,
        supervisor: &Supervisor<'_>,
        bus: &Bus,
        log: &Path,
    ) -> Result<()> {
        let mirror = self.mirror;
        let other_side = self.side.filter(|_| !self.passed);
        let within = if supervisor.ready(bus)? {
            Duration::ZERO
        } else if let Some(side) = other_side {
            eprintln!(
                "mirror {mirror}: {} side up; waiting for the {} side",
                side.name(),
                side.other().name()
            );
            OTHER_SIDE_WITHIN
        } else {
            READY_WITHIN
        };
        if within.is_zero() || wait_ready(supervisor, bus, within, &|| run.stopping())? {
            self.passed = true;
            return Ok(());
        }
        if run.stopping() {
            bail!("interrupted");
        }
        let other = other_side.map_or(String::new(), |s| {
            format!(
                "; is the {} side running and the link up?",
                s.other().name()
            )
        });
        bail!(
            "mirror {mirror}: the stages did not come up within {} s{other} ({})",
            within.as_secs(),
            see(log)
        );
    }
}

/// The settings every placement of a run shares.
pub struct Run {
    /// The run's settings.
    pub config: Config,
    /// Base `SCHED_FIFO` priority of the stages every sample waits for, when
    /// the config asks and the system allows ([`crate::scheduling`]).
    pub realtime: Option<u8>,
    /// The config file (attached to recordings).
    pub config_path: PathBuf,
    /// Output directory.
    pub out: PathBuf,
    /// Directory of the stage binaries.
    pub bin_dir: PathBuf,
    /// Service prefix; each placement appends `_m<i>`.
    pub prefix: String,
    /// Record each placement.
    pub record: bool,
    /// Serve the live view on this port.
    pub live_view: Option<u16>,
    /// ... on this address instead of 127.0.0.1.
    pub live_view_bind: Option<std::net::IpAddr>,
    /// Trace every stage step.
    pub trace: bool,
    /// This host's side of a split run and its link; `None`: every stage
    /// on this host.
    pub link: Option<Link>,
    /// Set by Ctrl-C.
    pub stop: Arc<AtomicBool>,
}

/// The simulated dataset of a placement and the pose plan made from it.
pub(crate) fn plan_for(config: &Config, mirror: usize) -> Result<(Dataset, Vec<PlannedPose>)> {
    let counts = Counts {
        train: config.train_poses,
        test: config.test_poses,
        direct: config.direct_poses,
    };
    let data = generate(&nico_scene(), mirror, &nico_noise(), counts, config.seed)?;
    let plan = [
        (&data.train, Role::Train),
        (&data.test, Role::Test),
        (&data.direct, Role::Direct),
    ]
    .into_iter()
    .flat_map(|(samples, role)| {
        samples.iter().map(move |s| PlannedPose {
            pose: s.pose,
            role,
            q: s.joints.clone().unwrap_or_default(),
        })
    })
    .collect::<Vec<_>>();
    let mut plan = plan;
    let events = crate::events::of_placement(&config.events, mirror);
    crate::events::extend_plan(&mut plan, &events, mirror, config.seed)?;
    Ok((data, plan))
}

/// What [`Run::conclude`] needs of a started placement.
struct Concluding<'a, 'b> {
    supervisor: Supervisor<'b>,
    bus: &'a Bus,
    launch: &'a Launch,
    mirror: usize,
    total: usize,
    time: Duration,
    dir: &'a Path,
    /// The mirror stage's report, where it runs here.
    stage_report: Option<&'a Path>,
    /// The recording, where the recorder runs here.
    recording: Option<PathBuf>,
    plan: &'a [PlannedPose],
    started: Instant,
}

/// The stages a placement starts on this host: `consumers` first, then,
/// once they listen, `after_ready`.
struct Here {
    consumers: Vec<StageArgs>,
    after_ready: Vec<StageArgs>,
}

/// Removes what an earlier run left at `path`, if anything.
fn clear(path: &Path) {
    let _ = std::fs::remove_file(path);
    let _ = std::fs::remove_dir_all(path);
}

impl Run {
    fn stopping(&self) -> bool {
        self.stop.load(Ordering::SeqCst)
    }

    /// Runs placement `mirror` end to end.
    pub fn placement(&self, mirror: usize) -> Result<PlacementResult> {
        let config = &self.config;
        let dir = self.out.join(format!("mirror{mirror}"));
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("{}: cannot create", dir.display()))?;
        let (data, plan) = plan_for(config, mirror)?;
        let rig = dir.join("rig.toml");
        // Live detections come from the tracker on renders, not from the
        // simulator's drawn pixel noise: the rig states none, and the
        // calibration judges against the tracker's own.
        // With [rig_error], the arm as a hand-measured rig would have it.
        let live_rig = geometry::Rig {
            pixel_sigma: None,
            ..config.rig_error.apply(&data.rig)
        };
        formats::rig::write(&rig, &live_rig)?;
        let plan_path = dir.join("plan.csv");
        formats::plan::write(&plan_path, &plan)?;
        let report_path = dir.join("report.json");
        let recording = dir.join("recording.mcap");
        // The mirror stage's and the arm driver's journals: a restart
        // within this run resumes from them; a new run starts new ones.
        let journal = dir.join("journal.mcap");
        let arm_journal = dir.join("arm_journal.mcap");
        let launch = Launch {
            realtime: self.realtime,
            ..Launch::in_dir(
                &self.bin_dir,
                format!("{}_m{mirror}", self.prefix),
                &dir,
                self.trace,
            )
        };
        for stale in [&report_path, &journal, &arm_journal]
            .into_iter()
            .chain(launch.outputs())
        {
            clear(stale);
        }
        let started = Instant::now();
        // The launcher holds every service for the whole run, so a stage that
        // crashes never takes a service down with it (see Bus::open_all).
        let bus = Bus::new(&launch.prefix, "pipeline")?;
        let _services = bus.open_all()?;

        // The stage table: consumers first (the recorder first of all), the
        // sources among them once those before them listen, then the arm
        // once every consumer listens.
        let prefix = &launch.prefix;
        let mut consumers: Vec<StageArgs> = Vec::new();
        if self.record {
            consumers.push(
                stages::recorder::Args {
                    prefix: prefix.clone(),
                    out: recording.clone(),
                    overwrite: true,
                    rig: Some(rig.clone()),
                    attach: vec![plan_path.clone(), self.config_path.clone()],
                    meta: vec![
                        ("mirror".into(), mirror.to_string()),
                        ("method".into(), config.method.to_string()),
                        ("fps".into(), config.fps.to_string()),
                    ],
                    live_view: self.live_view,
                    live_view_bind: self.live_view_bind,
                    ..Default::default()
                }
                .into(),
            );
        }
        if let Some(ros2) = config.ros2.as_ref().filter(|r| r.tf) {
            consumers.push(
                stages::ros2::TfArgs {
                    prefix: prefix.clone(),
                    rig: rig.clone(),
                    graph: ros2.graph(),
                    tf_static: "/tf_static".into(),
                    located: ros2.located_topic.clone(),
                }
                .into(),
            );
        }
        consumers.extend([
            stages::mirror::Args {
                method: config.method,
                min_train: config.min_train,
                report: Some(report_path.clone()),
                journal: Some(journal),
                ..stages::mirror::Args::new(prefix, &rig)
            }
            .into(),
            stages::tracker::Args {
                prefix: prefix.clone(),
                ..Default::default()
            }
            .into(),
            stages::camera::Args {
                prefix: prefix.clone(),
                mirror,
                fps: config.fps,
                look: config.look,
                changes: crate::events::changes(
                    &crate::events::of_placement(&config.events, mirror),
                    &plan,
                ),
                ..Default::default()
            }
            .into(),
            match (&config.ros2, config.arm_driver.as_deref()) {
                (Some(ros2), _) => stages::ros2::ArmArgs {
                    prefix: prefix.clone(),
                    rig: rig.clone(),
                    graph: ros2.graph(),
                    joint_states: ros2.joint_states.clone(),
                    trajectory: ros2.trajectory.clone(),
                    move_ms: config.move_ms,
                    silent_ms: 3000,
                }
                .into(),
                (None, None) => stages::sim_arm::Args {
                    prefix: prefix.clone(),
                    rig: rig.clone(),
                    move_ms: config.move_ms,
                    rate_hz: config.arm_rate_hz,
                }
                .into(),
                (None, Some(command)) => stages::arm_driver::Args {
                    command: shell_words::split(command)?,
                    prefix: prefix.clone(),
                    rig: rig.clone(),
                }
                .into(),
            },
        ]);
        let arm = stages::kinematics::Args {
            plan: Some(plan_path),
            dwell_ms: config.dwell_ms,
            journal: Some(arm_journal),
            ..stages::kinematics::Args::new(prefix, &rig)
        }
        .into();
        let side = self.link.as_ref().map(|l| l.side);
        let Here {
            consumers,
            mut after_ready,
        } = match &self.link {
            None => Here {
                consumers,
                after_ready: vec![arm],
            },
            Some(link) => self.split(link, prefix, mirror, consumers, arm),
        };
        for stage in &mut after_ready {
            if let StageArgs::Kinematics(kinematics) = stage {
                kinematics.wait_subscribers = subscribers_of(&consumers, TopicId::JointState);
            }
        }
        let mirror_here = consumers.iter().any(|s| matches!(s, StageArgs::Mirror(_)));
        let recorded_here = consumers
            .iter()
            .any(|s| matches!(s, StageArgs::Recorder(_)));

        let ends_run = if side == Some(Side::Robot) {
            "kinematics_proc"
        } else {
            "mirror_proc"
        };
        let mut supervisor = Supervisor::new(&launch, ends_run);
        // A source (a camera, an arm driver) starts only once every stage
        // before it listens: it publishes at once, and a recorder or a
        // tracker not yet subscribed would miss its first messages. On a
        // split run's robot that is when the workstation is up too (the
        // bridge subscribes once its receivers are on the link).
        let mut readiness = Readiness {
            side,
            mirror,
            passed: false,
        };
        // Sources come last: a consumer started after one could miss what
        // it published first.
        debug_assert!(
            consumers
                .iter()
                .skip_while(|s| !s.is_source())
                .all(StageArgs::is_source),
            "a consumer after a source in {consumers:?}"
        );
        let up = (|| -> Result<()> {
            for stage in consumers {
                if stage.is_source() {
                    readiness.wait(self, &supervisor, &bus, &launch.log)?;
                }
                supervisor.start(stage)?;
            }
            readiness.wait(self, &supervisor, &bus, &launch.log)?;
            for stage in after_ready {
                supervisor.start(stage)?;
            }
            Ok(())
        })();
        if let Err(e) = up {
            supervisor.stop();
            return Err(e);
        }
        let plan_seconds = plan.len() as f64 * (config.move_ms + config.dwell_ms) as f64 / 1000.0;
        let mut time = Duration::from_secs_f64(plan_seconds * 3.0 + 60.0);
        if side.is_some() {
            time += OTHER_SIDE_WITHIN;
        }
        self.conclude(Concluding {
            supervisor,
            bus: &bus,
            launch: &launch,
            mirror,
            total: plan.len(),
            time,
            dir: &dir,
            stage_report: mirror_here.then_some(report_path.as_path()),
            recording: recorded_here.then_some(recording),
            plan: &plan,
            started,
        })
    }

    /// This host's part of a placement's stage table (`consumers` and the
    /// arm, `arm`) on `link`'s side, with the bridge to the other side. On
    /// the robot the bridge starts first (it reads what the robot's stages
    /// publish, and subscribes only once the workstation's bridge is up, so
    /// the arm waits for the workstation) and stops last; on the
    /// workstation it starts once the stages there listen, as what sends
    /// them the robot's messages.
    fn split(
        &self,
        link: &Link,
        prefix: &str,
        mirror: usize,
        consumers: Vec<StageArgs>,
        arm: StageArgs,
    ) -> Here {
        let split = &self.config.split;
        let (here, there): (Vec<StageArgs>, Vec<StageArgs>) = consumers
            .into_iter()
            .chain([arm])
            .partition(|s| side_of(s, split) == link.side);
        let (here_refs, there_refs): (Vec<&StageArgs>, Vec<&StageArgs>) =
            (here.iter().collect(), there.iter().collect());
        let bridge = StageArgs::from(stages::bridge::Args {
            prefix: prefix.to_string(),
            namespace: Some(format!("{}/m{mirror}", link.namespace)),
            send: crossing(&here_refs, &there_refs),
            receive: crossing(&there_refs, &here_refs),
            listen: link.listen.clone(),
            connect: link.connect.clone(),
            compress_frames: split.compress_frames,
            lease_ms: split.lease_ms.unwrap_or(stages::bridge::DEFAULT_LEASE_MS),
            certs: link.certs.clone(),
            side: link.certs.as_ref().map(|_| link.side),
            insecure: link.insecure,
        });
        let (arm, consumers): (Vec<StageArgs>, Vec<StageArgs>) = here
            .into_iter()
            .partition(|s| matches!(s, StageArgs::Kinematics(_)));
        match link.side {
            Side::Robot => Here {
                consumers: [bridge].into_iter().chain(consumers).collect(),
                after_ready: arm,
            },
            Side::Workstation => Here {
                consumers,
                after_ready: [bridge].into_iter().chain(arm).collect(),
            },
        }
    }

    /// Re-runs the stages downstream of `kind` (`frames`: tracker and
    /// mirror stage; `detections`: the mirror stage) on the recording at
    /// `file`, recording them into `self.out/recording.mcap`. The rig, plan
    /// and config are the ones the recording holds (written into
    /// `self.out` by the caller); `mirror` is its placement.
    pub fn replay(
        &self,
        file: &Path,
        kind: stages::replay::Kind,
        mirror: usize,
    ) -> Result<PlacementResult> {
        let config = &self.config;
        let dir = self.out.clone();
        let (_, plan) = plan_for(config, mirror)?;
        let rig = dir.join("rig.toml");
        let report_path = dir.join("mirror_report.json");
        let recording = dir.join("recording.mcap");
        let journal = dir.join("journal.mcap");
        let launch = Launch::in_dir(&self.bin_dir, self.prefix.clone(), &dir, self.trace);
        for stale in [&report_path, &journal, &recording]
            .into_iter()
            .chain(launch.outputs())
        {
            clear(stale);
        }
        let started = Instant::now();
        let bus = Bus::new(&launch.prefix, "pipeline")?;
        let mut supervisor = Supervisor::new(&launch, "mirror_proc");
        let replayed = kind.topics();
        let prefix = &launch.prefix;
        let mut table: Vec<StageArgs> = Vec::new();
        if self.record {
            table.push(
                stages::recorder::Args {
                    prefix: prefix.clone(),
                    out: recording.clone(),
                    overwrite: true,
                    no_drop: true,
                    rig: Some(rig.clone()),
                    attach: vec![dir.join("plan.csv"), self.config_path.clone()],
                    meta: vec![
                        ("mirror".into(), mirror.to_string()),
                        ("method".into(), config.method.to_string()),
                        ("fps".into(), config.fps.to_string()),
                        ("replay_of".into(), file.display().to_string()),
                        ("replay_kind".into(), kind.name().into()),
                    ],
                    live_view: self.live_view,
                    live_view_bind: self.live_view_bind,
                    ..Default::default()
                }
                .into(),
            );
        }
        table.push(
            stages::mirror::Args {
                method: config.method,
                min_train: config.min_train,
                report: Some(report_path.clone()),
                journal: Some(journal),
                ..stages::mirror::Args::new(prefix, &rig)
            }
            .into(),
        );
        if kind == stages::replay::Kind::Frames {
            table.push(
                stages::tracker::Args {
                    prefix: prefix.clone(),
                    ..Default::default()
                }
                .into(),
            );
        }
        // Each replayed topic waits for every stage that reads it.
        let wait_subscribers = replayed
            .iter()
            .map(|t| subscribers_of(&table, *t))
            .min()
            .unwrap_or(0);
        supervisor.start(
            stages::replay::Args {
                kind,
                wait_subscribers,
                ..stages::replay::Args::new(file, prefix)
            }
            .into(),
        )?;
        // Replay creates every service lossless (publishers wait for the
        // slowest subscriber), its topics' and the rest; nothing may create
        // one before it does (then its settings differ and replay fails).
        let waited = Instant::now();
        while !TopicId::ALL
            .iter()
            .all(|t| bus.service_exists(*t).unwrap_or(false))
        {
            if waited.elapsed() > READY_WITHIN || !supervisor.is_running("replay") {
                supervisor.stop();
                bail!("replay did not create its services ({})", see(&launch.log));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _services = bus.open_all()?;
        for stage in table {
            if let Err(e) = supervisor.start(stage) {
                supervisor.stop();
                return Err(e);
            }
        }
        self.conclude(Concluding {
            supervisor,
            bus: &bus,
            launch: &launch,
            mirror,
            total: plan.len(),
            time: Duration::from_secs(600),
            dir: &dir,
            stage_report: Some(&report_path),
            recording: self.record.then_some(recording),
            plan: &plan,
            started,
        })
    }

    /// Follows a placement's stages until the run ends, stops them, and
    /// reads and evaluates the mirror stage's report.
    fn conclude(&self, c: Concluding<'_, '_>) -> Result<PlacementResult> {
        let Concluding {
            mut supervisor,
            bus,
            launch,
            mirror,
            total,
            time,
            dir,
            stage_report: report_path,
            recording,
            plan,
            started,
        } = c;
        let outcome = self.follow(&mut supervisor, bus, mirror, total, time);
        let recorded = supervisor.is_running("recorder");
        let stopped = supervisor.stop();
        for line in &stopped.unclean {
            eprintln!("mirror {mirror}: stopping {line}");
        }
        match outcome? {
            Progress::Done => {}
            Progress::Running => bail!(
                "mirror {mirror}: the run did not finish in time ({})",
                see(&launch.log)
            ),
            Progress::Failed(name) => bail!("{name} keeps failing ({})", see(&launch.log)),
        }
        if let Some(t) = &launch.trace_dir {
            let merged = dir.join("trace.json");
            let events = runtime::trace::merge(t, &merged)
                .with_context(|| format!("{}: cannot merge the traces", t.display()))?;
            eprintln!(
                "trace: {} ({events} events; open in https://ui.perfetto.dev)",
                merged.display()
            );
        }
        let report = report_path
            .map(|path| -> Result<LiveReport> {
                serde_json::from_str(
                    &std::fs::read_to_string(path)
                        .with_context(|| format!("{}: missing", path.display()))?,
                )
                .with_context(|| format!("{}: unreadable", path.display()))
            })
            .transpose()?;
        let events = crate::events::of_placement(&self.config.events, mirror);
        let worlds = crate::events::worlds(&events, plan, mirror)?;
        let last_world = &worlds[worlds.len() - 1].1;
        let truth = report.as_ref().map(|r| TruthErrors::of(r, last_world));
        let epochs = match &report {
            Some(r) if !events.is_empty() => crate::events::epoch_truths(r, &worlds, plan),
            _ => Vec::new(),
        };
        Ok(PlacementResult {
            mirror,
            report,
            truth,
            epochs,
            restarts: stopped.restarts,
            seconds: started.elapsed().as_secs_f64(),
            recording: recording.filter(|_| recorded),
            stages: runtime::stats::read_all(&launch.stats_dir),
        })
    }

    /// Shows the progress from the stages' outputs and watches the stages
    /// until the run is done, fails, is interrupted or runs out of `time`.
    fn follow(
        &self,
        supervisor: &mut Supervisor<'_>,
        bus: &Bus,
        mirror: usize,
        total: usize,
        time: Duration,
    ) -> Result<Progress> {
        let samples = bus.subscriber::<topics::Samples>()?;
        let calibrations = bus.subscriber::<topics::Calibration>()?;
        let (mut paired, mut last_cal) = (0usize, None::<CalibrationMsg>);
        let terminal = std::io::stderr().is_terminal();
        let mut shown = String::new();
        let deadline = Instant::now() + time;
        let progress = loop {
            while samples.receive()?.is_some() {
                paired += 1;
            }
            while let Some(c) = calibrations.receive()? {
                last_cal = Some(c);
            }
            let line = format!(
                "mirror {mirror}: {paired}/{total} poses paired, calibration revision {} (train RMS {:.2} px)",
                last_cal.map_or(0, |c| c.revision),
                last_cal.map_or(f64::NAN, |c| c.train_rms_px)
            );
            if line != shown {
                if terminal {
                    eprint!("\r{line}   ")
                } else {
                    eprintln!("{line}")
                }
                shown = line;
            }
            if self.stopping() {
                bail!("interrupted");
            }
            match supervisor.watch()? {
                Progress::Running if Instant::now() > deadline => break Progress::Running,
                Progress::Running => std::thread::sleep(Duration::from_millis(50)),
                done_or_failed => break done_or_failed,
            }
        };
        if terminal {
            eprintln!();
        }
        Ok(progress)
    }
}
