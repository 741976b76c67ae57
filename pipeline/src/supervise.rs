//! Starting, watching, restarting and stopping the stage processes of one
//! placement, as their specs say.

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use messages::topics::TopicId;
use runtime::Bus;

use stages::{RestartPolicy, StageArgs, subscribers_of};

/// Restarts allowed per stage before the run fails.
pub const MAX_RESTARTS: u32 = 3;

/// Where and how a placement's stages are started.
pub struct Launch {
    /// Directory of the stage binaries.
    pub bin_dir: PathBuf,
    /// The pipeline's service prefix.
    pub prefix: String,
    /// Every stage's stderr, appended.
    pub log: PathBuf,
    /// Trace directory (`MIRROR_TRACE_DIR`), when tracing.
    pub trace_dir: Option<PathBuf>,
    /// Where the stages write their timing (`MIRROR_STATS_DIR`).
    pub stats_dir: PathBuf,
    /// Base `SCHED_FIFO` priority for the stages every sample waits for
    /// (each runs its [`StageArgs::sample_path_depth`] above it); `None`: the
    /// launcher's scheduling.
    pub realtime: Option<u8>,
}

impl Launch {
    /// Stages of `bin_dir` on `prefix`, with their log, stats and (when
    /// `trace`) traces in `dir`.
    pub fn in_dir(bin_dir: &Path, prefix: String, dir: &Path, trace: bool) -> Self {
        Self {
            bin_dir: bin_dir.to_path_buf(),
            prefix,
            log: dir.join("stages.log"),
            trace_dir: trace.then(|| dir.join("trace")),
            stats_dir: dir.join("stats"),
            realtime: None,
        }
    }

    /// What an earlier run left in its log, stats and trace paths.
    pub fn outputs(&self) -> impl Iterator<Item = &PathBuf> {
        [&self.log, &self.stats_dir]
            .into_iter()
            .chain(&self.trace_dir)
    }

    fn spawn(&self, stage: &StageArgs) -> Result<Child> {
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.log)
            .with_context(|| format!("{}: cannot open", self.log.display()))?;
        let binary = stage.program(&self.bin_dir);
        let mut command = Command::new(&binary);
        if let Some(dir) = &self.trace_dir {
            command.env(runtime::trace::TRACE_DIR_ENV, dir);
        }
        command.env(runtime::stats::STATS_DIR_ENV, &self.stats_dir);
        let niceness = stage.niceness();
        let realtime = self
            .realtime
            .zip(stage.sample_path_depth())
            .map(|(base, depth)| base + depth);
        // SAFETY: prctl(2), setpriority(2) and sched_setscheduler(2) only,
        // between fork and exec. The stages are told to stop (SIGTERM, so the
        // recorder finishes its file) if the launcher dies; a stage off the
        // frame-to-sample path runs at a lower priority, one on it (when the
        // run asks and the launcher found it allowed) before every normally
        // scheduled process, its threads too (they inherit the policy).
        #[allow(unsafe_code)]
        unsafe {
            command.pre_exec(move || {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) == -1 {
                    return Err(std::io::Error::last_os_error());
                }
                if niceness != 0 && libc::setpriority(libc::PRIO_PROCESS, 0, niceness) == -1 {
                    return Err(std::io::Error::last_os_error());
                }
                // The child has one thread: this puts the whole process there.
                if let Some(priority) = realtime {
                    runtime::realtime::fifo_this_thread(priority)?;
                }
                Ok(())
            });
        }
        // A live recorder takes messages out of shared memory on a thread at
        // the base priority, so that the stages above it cannot starve it of
        // frames; it compresses and writes at its niceness.
        let mut stage = stage.clone();
        if let (Some(base), StageArgs::Recorder(recorder)) = (self.realtime, &mut stage)
            && !recorder.no_drop
        {
            recorder.realtime_priority = Some(base);
        }
        command
            .args(stage.argv())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .with_context(|| {
                format!(
                    "cannot start {} (build the workspace binaries first)",
                    binary.display()
                )
            })
    }
}

/// A started stage.
struct Running {
    stage: StageArgs,
    child: Child,
    restarts: u32,
}

/// What the stages are doing.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Progress {
    /// Still running (crashed stages were restarted).
    Running,
    /// The stage that ends the run has finished.
    Done,
    /// A stage failed more often than it may be restarted.
    Failed(&'static str),
}

/// How the stages ended.
#[derive(Debug, Clone, Default)]
pub struct Stopped {
    /// Restarts of every stage.
    pub restarts: u32,
    /// Stages that had to be killed or did not exit cleanly, with why.
    pub unclean: Vec<String>,
}

/// The running stages of one placement.
pub struct Supervisor<'a> {
    launch: &'a Launch,
    /// The stage whose successful exit ends the run.
    ends_run: &'static str,
    /// In start order.
    running: Vec<Running>,
}

impl<'a> Supervisor<'a> {
    /// No stages yet; the run ends when the stage named `ends_run` (its
    /// [`StageArgs::binary`]) exits successfully: the mirror stage where it
    /// runs, the kinematics stage on the robot side of a split run.
    pub fn new(launch: &'a Launch, ends_run: &'static str) -> Self {
        Self {
            launch,
            ends_run,
            running: Vec::new(),
        }
    }

    /// Starts `stage`.
    pub fn start(&mut self, stage: StageArgs) -> Result<()> {
        let child = self.launch.spawn(&stage)?;
        self.running.push(Running {
            stage,
            child,
            restarts: 0,
        });
        Ok(())
    }

    /// Whether `binary` was started and is still in the run (an optional
    /// stage that stopped is not).
    pub fn is_running(&self, binary: &str) -> bool {
        self.running.iter().any(|r| r.stage.binary() == binary)
    }

    /// Whether every started stage has subscribed to what its spec says.
    pub fn ready(&self, bus: &Bus) -> Result<bool> {
        for topic in TopicId::ALL {
            let expected = subscribers_of(self.running.iter().map(|r| &r.stage), topic);
            if bus.subscriber_count(topic)? < expected {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// Looks at every stage once: restarts a crashed one (as its policy
    /// allows), drops an optional one that stopped, and says whether the
    /// run is done or failed.
    pub fn watch(&mut self) -> Result<Progress> {
        let mut progress = Progress::Running;
        let mut gone = Vec::new();
        for (i, r) in self.running.iter_mut().enumerate() {
            let Some(status) = r.child.try_wait()? else {
                continue;
            };
            let policy = r.stage.restart_policy();
            let name = r.stage.binary();
            match policy {
                _ if status.success() && name == self.ends_run => progress = Progress::Done,
                RestartPolicy::Finishes if status.success() => {}
                RestartPolicy::Optional => {
                    eprintln!(
                        "\n{name} exited ({status}); the run goes on without it (see {})",
                        self.launch.log.display()
                    );
                    gone.push(i);
                }
                _ if r.restarts < MAX_RESTARTS => {
                    eprintln!("\n{name} exited ({status}); restarting it");
                    r.restarts += 1;
                    r.child = self.launch.spawn(&r.stage)?;
                }
                _ => return Ok(Progress::Failed(name)),
            }
        }
        for i in gone.into_iter().rev() {
            self.running.remove(i);
        }
        Ok(progress)
    }

    /// Stops the stages in the reverse of their start order (sources
    /// first, the recorder last), each after the previous has exited, so
    /// every consumer takes what its sources sent before it stops.
    pub fn stop(mut self) -> Stopped {
        let mut stopped = Stopped {
            restarts: self.running.iter().map(|r| r.restarts).sum(),
            ..Default::default()
        };
        while let Some(mut r) = self.running.pop() {
            if let Some(why) = stop_child(&mut r.child, r.stage.stop_grace()) {
                stopped.unclean.push(format!("{}: {why}", r.stage.binary()));
            }
        }
        stopped
    }
}

/// SIGINT (so iceoryx2 stages leave their services cleanly and the
/// recorder finishes its file), then SIGKILL after `grace`; says what went
/// wrong, if anything.
fn stop_child(child: &mut Child, grace: Duration) -> Option<String> {
    if let Ok(Some(status)) = child.try_wait() {
        return (!status.success()).then(|| format!("had exited ({status})"));
    }
    // SAFETY: kill(2) on a child pid we own and have not reaped.
    #[allow(unsafe_code)]
    unsafe {
        libc::kill(child.id() as i32, libc::SIGINT)
    };
    let deadline = Instant::now() + grace;
    while Instant::now() < deadline {
        match child.try_wait() {
            Ok(Some(status)) if status.success() => return None,
            Ok(Some(status)) => return Some(format!("exited ({status})")),
            _ => std::thread::sleep(Duration::from_millis(10)),
        }
    }
    let _ = child.kill();
    let _ = child.wait();
    Some(format!("did not stop within {} s", grace.as_secs()))
}

/// Waits until `supervisor`'s stages are ready, or `limit` passes or `stop` is set.
pub fn wait_ready(
    supervisor: &Supervisor<'_>,
    bus: &Bus,
    limit: Duration,
    stop: &dyn Fn() -> bool,
) -> Result<bool> {
    let began = Instant::now();
    while !supervisor.ready(bus)? {
        if began.elapsed() > limit || stop() {
            return Ok(false);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(true)
}

/// The log of a placement, for error messages.
pub fn see(log: &Path) -> String {
    format!("see {}", log.display())
}
