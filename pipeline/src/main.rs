//! `pipeline`: runs the whole live pipeline on the simulated robot, one
//! mirror placement after another, and prints the paper's table for the run.
//!
//! Per placement it writes `rig.toml` and `plan.csv` into `OUT/mirror<i>/`,
//! starts `recorder` (unless `--no-record`), `mirror_proc`, `tracker_proc`
//! and `camera_proc`, waits until they are subscribed, then starts
//! `kinematics_proc` on the plan. A stage that
//! crashes is restarted (it reattaches to the same services). When the
//! plan is done `mirror_proc` writes `report.json`; the launcher stops the
//! rest, evaluates the calibration against the simulator's truth and writes
//! `OUT/report.json`. Ctrl-C stops every stage cleanly.

use std::io::IsTerminal;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Parser;
use geometry::sim::{Counts, generate, nico_noise, nico_scene};
use kinematics_proc::{PlannedPose, write_plan};
use messages::topics::{self, TopicId};
use messages::{Bus, CalibrationMsg, role};
use mirror_proc::calibrate::Method;
use mirror_proc::experiment::{PAPER_FIGURES, rotation_error};
use mirror_proc::live::LiveReport;
use serde::{Deserialize, Serialize};

/// Run the live pipeline on the simulated robot.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    /// Config file (TOML); see pipeline.toml.
    #[arg(long, default_value = "pipeline.toml")]
    config: PathBuf,
    /// Output directory.
    #[arg(long, default_value = "out/pipeline")]
    out: PathBuf,
    /// Mirror placements to run (overrides the config), e.g. 0,2.
    #[arg(long, value_delimiter = ',')]
    mirrors: Option<Vec<usize>>,
    /// Calibration poses per placement (overrides the config).
    #[arg(long)]
    poses: Option<usize>,
    /// Calibration method (overrides the config).
    #[arg(long)]
    method: Option<String>,
    /// Camera frame rate, Hz (overrides the config).
    #[arg(long)]
    fps: Option<f64>,
    /// Service prefix (default: unique per run).
    #[arg(long)]
    prefix: Option<String>,
    /// Do not record (by default each placement is recorded into
    /// `OUT/mirror<i>/recording.mcap`).
    #[arg(long)]
    no_record: bool,
    /// Serve the viewing channels live to Foxglove on this localhost port
    /// (ws://127.0.0.1:PORT) while the pipeline runs.
    #[arg(long)]
    live_view: Option<u16>,
    /// What to print at the end: the tables, or the whole report as JSON.
    #[arg(long, value_enum, default_value_t = ReportFormat::Table)]
    report: ReportFormat,
    /// Trace every stage step of every process into
    /// `OUT/mirror<i>/trace.json` (Chrome trace format; open it in Perfetto).
    #[arg(long)]
    trace: bool,
}

/// The form of the final report on stdout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ReportFormat {
    /// The paper's table and the latency table.
    Table,
    /// The full report (the same as OUT/report.json).
    Json,
}

/// Recording, live view and tracing settings of a run.
#[derive(Debug, Clone)]
struct RunExtras {
    enabled: bool,
    live_view: Option<u16>,
    config_path: PathBuf,
    trace: bool,
}

/// The run's settings.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Config {
    preset: String,
    mirrors: Vec<usize>,
    train_poses: usize,
    test_poses: usize,
    direct_poses: usize,
    method: String,
    source: String,
    fps: f64,
    move_ms: u64,
    dwell_ms: u64,
    seed: u64,
    min_train: usize,
}

/// What the table shows for one placement.
#[derive(Debug, Clone, Serialize)]
struct PlacementResult {
    mirror: usize,
    report: LiveReport,
    plane_angle_deg: Option<f64>,
    plane_distance_mm: Option<f64>,
    camera_center_mm: Option<[f64; 2]>,
    camera_rotation_deg: Option<[f64; 2]>,
    hidden_object_error_mm: Option<f64>,
    restarts: u32,
    seconds: f64,
    recording: Option<PathBuf>,
    /// Each stage process's latencies (HDR histograms) and counters.
    stages: Vec<messages::stats::StageSummary>,
}

struct Stage {
    name: &'static str,
    args: Vec<String>,
    child: Child,
    restarts: u32,
}

const MAX_RESTARTS: u32 = 3;

impl Stage {
    fn spawn(launch: &Launch<'_>, name: &'static str, args: Vec<String>) -> Result<Self> {
        let child = spawn(launch, name, &args)?;
        Ok(Self {
            name,
            args,
            child,
            restarts: 0,
        })
    }
}

/// Where and how a placement's stages are started.
struct Launch<'a> {
    bin_dir: &'a Path,
    /// Every stage's stderr, appended.
    log: PathBuf,
    /// Trace directory (`MIRROR_TRACE_DIR`), when tracing.
    trace_dir: Option<PathBuf>,
    /// Where the stages write their timing (`MIRROR_STATS_DIR`).
    stats_dir: PathBuf,
}

fn spawn(launch: &Launch<'_>, name: &str, args: &[String]) -> Result<Child> {
    let bin_dir = launch.bin_dir;
    let log_file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&launch.log)?;
    let mut command = Command::new(bin_dir.join(name));
    if let Some(dir) = &launch.trace_dir {
        command.env(messages::trace::TRACE_DIR_ENV, dir);
    }
    command.env(messages::stats::STATS_DIR_ENV, &launch.stats_dir);
    // SAFETY: prctl(2) only, between fork and exec. The stages are told to
    // stop (SIGTERM, so the recorder finishes its file) if the launcher dies.
    unsafe {
        command.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) == -1 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    command
        .args(args)
        .stdout(Stdio::null())
        .stderr(log_file)
        .spawn()
        .with_context(|| {
            format!(
                "cannot start {} (build the workspace binaries first)",
                bin_dir.join(name).display()
            )
        })
}

fn interrupt(child: &mut Child) {
    // SIGINT lets iceoryx2 stages leave their services cleanly.
    // SAFETY: kill(2) on a child pid we own.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
}

/// Stops the stages sources first (they were started consumers first), each
/// after the previous has exited, so every consumer takes what its sources
/// sent before it stops.
fn stop(stages: &mut [Stage]) {
    for s in stages.iter_mut().rev() {
        interrupt(&mut s.child);
        let deadline = Instant::now() + Duration::from_secs(3);
        while Instant::now() < deadline && matches!(s.child.try_wait(), Ok(None)) {
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = s.child.kill();
        let _ = s.child.wait();
    }
}

fn plan_for(config: &Config, mirror: usize) -> Result<(geometry::sim::Dataset, Vec<PlannedPose>)> {
    let counts = Counts {
        train: config.train_poses,
        test: config.test_poses,
        direct: config.direct_poses,
    };
    let data = generate(&nico_scene(), mirror, &nico_noise(), counts, config.seed)?;
    let plan = [
        (&data.train, role::TRAIN),
        (&data.test, role::TEST),
        (&data.direct, role::DIRECT),
    ]
    .into_iter()
    .flat_map(|(samples, r)| {
        samples.iter().map(move |s| PlannedPose {
            pose: s.pose,
            role: r,
            q: s.joints.clone().unwrap_or_default(),
        })
    })
    .collect();
    Ok((data, plan))
}

/// Stops the recorder last, once every source has stopped, and gives it
/// time to take what is waiting and finish the file.
fn stop_recorder(recorder: Option<Child>, path: &Path) -> Option<PathBuf> {
    let mut child = recorder?;
    interrupt(&mut child);
    let deadline = Instant::now() + Duration::from_secs(60);
    while Instant::now() < deadline && matches!(child.try_wait(), Ok(None)) {
        std::thread::sleep(Duration::from_millis(20));
    }
    match child.try_wait() {
        Ok(Some(status)) if status.success() => Some(path.to_path_buf()),
        Ok(Some(status)) => {
            eprintln!(
                "recorder exited ({status}); {} may end early",
                path.display()
            );
            Some(path.to_path_buf())
        }
        _ => {
            let _ = child.kill();
            let _ = child.wait();
            eprintln!(
                "recorder did not finish in 60 s; {} may end early",
                path.display()
            );
            Some(path.to_path_buf())
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn run_placement(
    config: &Config,
    mirror: usize,
    out: &Path,
    prefix: &str,
    bin_dir: &Path,
    stop_flag: &AtomicBool,
    extras: &RunExtras,
) -> Result<PlacementResult> {
    let dir = out.join(format!("mirror{mirror}"));
    std::fs::create_dir_all(&dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    let (data, plan) = plan_for(config, mirror)?;
    let rig_path = dir.join("rig.toml");
    formats::rig::write(&rig_path, &data.rig)?;
    let plan_path = dir.join("plan.csv");
    write_plan(&plan_path, &plan)?;
    let report_path = dir.join("report.json");
    let _ = std::fs::remove_file(&report_path);
    let log = dir.join("stages.log");
    let _ = std::fs::remove_file(&log);
    let trace_dir = extras.trace.then(|| dir.join("trace"));
    if let Some(t) = &trace_dir {
        let _ = std::fs::remove_dir_all(t);
    }
    let stats_dir = dir.join("stats");
    let _ = std::fs::remove_dir_all(&stats_dir);
    let launch = Launch {
        bin_dir,
        log: log.clone(),
        trace_dir: trace_dir.clone(),
        stats_dir: stats_dir.clone(),
    };
    let s = |v: &str| v.to_string();
    let started = Instant::now();
    // The launcher holds every service for the whole run, so a stage that
    // crashes never takes a service down with it (see Bus::open_all).
    let bus = Bus::new(prefix, "pipeline")?;
    let _services = bus.open_all()?;
    // The recorder first, so it sees every message; it is not restarted
    // (a restart would overwrite the file) and its failure does not stop the run.
    let recording_path = dir.join("recording.mcap");
    let mut recorder = if extras.enabled {
        let mut args = vec![
            s("--prefix"),
            s(prefix),
            s("--out"),
            recording_path.display().to_string(),
            s("--overwrite"),
            s("--rig"),
            rig_path.display().to_string(),
            s("--attach"),
            plan_path.display().to_string(),
            s("--attach"),
            extras.config_path.display().to_string(),
            s("--meta"),
            format!("mirror={mirror}"),
            s("--meta"),
            format!("method={}", config.method),
            s("--meta"),
            format!("fps={}", config.fps),
        ];
        if let Some(port) = extras.live_view {
            args.extend([s("--live-view"), port.to_string()]);
        }
        Some(spawn(&launch, "recorder", &args)?)
    } else {
        None
    };
    let mut stages = vec![
        Stage::spawn(
            &launch,
            "mirror_proc",
            vec![
                s("run"),
                s("--prefix"),
                s(prefix),
                s("--rig"),
                rig_path.display().to_string(),
                s("--method"),
                config.method.clone(),
                s("--min-train"),
                config.min_train.to_string(),
                s("--report"),
                report_path.display().to_string(),
            ],
        )?,
        Stage::spawn(
            &launch,
            "tracker_proc",
            vec![s("run"), s("--prefix"), s(prefix)],
        )?,
        Stage::spawn(
            &launch,
            "camera_proc",
            vec![
                s("sim"),
                s("--prefix"),
                s(prefix),
                s("--mirror"),
                mirror.to_string(),
                s("--fps"),
                config.fps.to_string(),
            ],
        )?,
    ];
    // Start the arm only once every consumer listens.
    let ready = Instant::now();
    loop {
        let frames = bus.subscriber_count(TopicId::Frames)?;
        let dets = bus.subscriber_count(TopicId::Detections)?;
        let joints = bus.subscriber_count(TopicId::JointState)?;
        let extra = usize::from(recorder.is_some());
        if frames > extra && dets > extra && joints >= 2 + extra {
            break;
        }
        if ready.elapsed() > Duration::from_secs(30) || stop_flag.load(Ordering::SeqCst) {
            stop(&mut stages);
            stop_recorder(recorder.take(), &recording_path);
            bail!(
                "mirror {mirror}: the stages did not come up within 30 s (see {})",
                log.display()
            );
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let kin_args = vec![
        s("--prefix"),
        s(prefix),
        s("--rig"),
        rig_path.display().to_string(),
        s("--plan"),
        plan_path.display().to_string(),
        s("--move-ms"),
        config.move_ms.to_string(),
        s("--dwell-ms"),
        config.dwell_ms.to_string(),
        s("--wait-subscribers"),
        (2 + usize::from(recorder.is_some())).to_string(),
    ];
    stages.push(Stage::spawn(&launch, "kinematics_proc", kin_args)?);
    // Progress from the stage outputs.
    let samples = bus.subscriber::<topics::Samples>()?;
    let calibrations = bus.subscriber::<topics::Calibration>()?;
    let (mut paired, mut last_cal) = (0usize, None::<CalibrationMsg>);
    let terminal = std::io::stderr().is_terminal();
    let mut shown = String::new();
    let total = plan.len();
    let plan_seconds = total as f64 * (config.move_ms + config.dwell_ms) as f64 / 1000.0;
    let deadline = Instant::now() + Duration::from_secs_f64(plan_seconds * 3.0 + 60.0);
    loop {
        while let Some(_s) = samples.receive()? {
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
        if stop_flag.load(Ordering::SeqCst) {
            stop(&mut stages);
            stop_recorder(recorder.take(), &recording_path);
            bail!("interrupted");
        }
        if Instant::now() > deadline {
            stop(&mut stages);
            stop_recorder(recorder.take(), &recording_path);
            bail!(
                "mirror {mirror}: the run did not finish in time (see {})",
                log.display()
            );
        }
        // mirror_proc (index 0) ends the run; kinematics ends by itself; others are restarted if they crash.
        let mut done = false;
        let mut failed = None;
        for (i, stage) in stages.iter_mut().enumerate() {
            if let Some(status) = stage.child.try_wait()? {
                let finished_normally = status.success()
                    && (i == 0 || stage.name == "kinematics_proc" || stage.name == "camera_proc");
                if i == 0 && status.success() {
                    done = true;
                } else if !finished_normally && stage.restarts < MAX_RESTARTS {
                    eprintln!("\n{} exited ({status}); restarting it", stage.name);
                    stage.restarts += 1;
                    stage.child = spawn(&launch, stage.name, &stage.args)?;
                } else if !finished_normally {
                    failed = Some(stage.name);
                }
            }
        }
        if let Some(r) = recorder.as_mut()
            && let Some(status) = r.try_wait()?
        {
            eprintln!(
                "\nrecorder exited ({status}); the run goes on unrecorded (see {})",
                log.display()
            );
            recorder = None;
        }
        if let Some(name) = failed {
            stop(&mut stages);
            stop_recorder(recorder.take(), &recording_path);
            bail!("{name} keeps failing (see {})", log.display());
        }
        if done {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    if terminal {
        eprintln!();
    }
    let restarts = stages.iter().map(|s| s.restarts).sum();
    stop(&mut stages);
    let recording_file = stop_recorder(recorder.take(), &recording_path);
    if let Some(t) = &trace_dir {
        let merged = dir.join("trace.json");
        let events = messages::trace::merge(t, &merged)
            .with_context(|| format!("{}: cannot merge the traces", t.display()))?;
        eprintln!(
            "trace: {} ({events} events; open in https://ui.perfetto.dev)",
            merged.display()
        );
    }
    let report: LiveReport = serde_json::from_str(
        &std::fs::read_to_string(&report_path)
            .with_context(|| format!("{}: missing", report_path.display()))?,
    )
    .with_context(|| format!("{}: unreadable", report_path.display()))?;
    if report.calibration.is_none() {
        eprintln!(
            "mirror {mirror}: no calibration: {}",
            report.last_error.as_deref().unwrap_or("no reason given")
        );
    }
    // Against the simulator's truth.
    let truth_plane = data.truth.mirror.plane;
    let cal = report.calibration.as_ref();
    let cams = cal.map(|c| c.mirror_cameras(&data.rig));
    let plane = cal.and_then(|c| c.plane());
    let hidden = geometry::sim::SimWorld::nico(mirror)?
        .fixed
        .first()
        .map(|f| f.center);
    let hidden_error = hidden.and_then(|h| {
        report
            .located
            .get(&geometry::sim::HIDDEN_OBJECT_ID)
            .map(|p| (nalgebra::Vector3::from(*p) - h).norm())
    });
    Ok(PlacementResult {
        mirror,
        plane_angle_deg: plane.map(|p| {
            p.normal
                .dot(&truth_plane.normal)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        }),
        plane_distance_mm: plane.map(|p| (p.distance - truth_plane.distance).abs()),
        camera_center_mm: cams
            .map(|c| [0, 1].map(|k| (c[k].center - data.truth.mirror_cameras[k].center).norm())),
        camera_rotation_deg: cams.map(|c| {
            [0, 1].map(|k| rotation_error(&c[k], &data.truth.mirror_cameras[k]).to_degrees())
        }),
        hidden_object_error_mm: hidden_error,
        report,
        restarts,
        seconds: started.elapsed().as_secs_f64(),
        recording: recording_file,
        stages: messages::stats::read_all(&stats_dir),
    })
}

fn cell(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.2}"))
}

/// Per stage and placement: latency percentiles (from each stage's HDR
/// histograms) and the drop counters.
fn latency_table(results: &[PlacementResult]) -> String {
    let mut s = String::from("\nLatency per stage, ms (HDR histograms)\n");
    s += &format!(
        "  {:<10} {:<14} {:<20} {:>7} {:>8} {:>8} {:>8} {:>8}\n",
        "placement", "stage", "", "count", "median", "p90", "p99", "max"
    );
    for r in results {
        for stage in &r.stages {
            for (name, l) in &stage.latencies {
                s += &format!(
                    "  {:<10} {:<14} {:<20} {:>7} {:>8.2} {:>8.2} {:>8.2} {:>8.2}\n",
                    format!("mirror {}", r.mirror),
                    stage.stage,
                    name,
                    l.count,
                    l.p50_ms,
                    l.p90_ms,
                    l.p99_ms,
                    l.max_ms
                );
            }
        }
        let counters: Vec<String> = r
            .stages
            .iter()
            .flat_map(|st| {
                st.counters
                    .iter()
                    .filter(|(k, _)| {
                        k.contains("missed")
                            || k.contains("dropped")
                            || k.contains("rejected")
                            || k.contains("late")
                            || k.contains("restarts")
                            || k.contains("repeated")
                    })
                    .map(move |(k, v)| format!("{} {k} {v}", st.stage))
            })
            .collect();
        s += &format!("  mirror {} drops: {}\n", r.mirror, counters.join(", "));
    }
    s
}

fn table(results: &[PlacementResult], method: &str) -> String {
    let mut s = format!(
        "Live pipeline, method {method}: mean errors on the test poses of each placement\n"
    );
    s += &format!(
        "  {:<30} {:>12} {:>12} {:>12} {:>12} {:>10} {:>10}\n",
        "",
        "mirror 3D mm",
        "direct 3D mm",
        "mirror 2D px",
        "direct 2D px",
        "plane deg",
        "object mm"
    );
    let p = PAPER_FIGURES;
    s += &format!(
        "  {:<30} {:>12.2} {:>12.2} {:>12.2} {:>12.2} {:>10} {:>10}\n",
        "Hart & Scassellati 2012 (Nico)",
        p.mirror_3d_mm,
        p.direct_3d_mm,
        p.mirror_2d_px,
        p.direct_2d_px,
        "-",
        "-"
    );
    let mut sums = [0.0; 6];
    let mut counts = [0usize; 6];
    for r in results {
        let e = r.report.evaluation.as_ref();
        let values = [
            e.and_then(|e| e.mirror_3d_mm),
            e.and_then(|e| e.direct_3d_mm),
            e.and_then(|e| e.mirror_2d_px),
            e.and_then(|e| e.direct_2d_px),
            r.plane_angle_deg,
            r.hidden_object_error_mm,
        ];
        for (i, v) in values.iter().enumerate() {
            if let Some(v) = v {
                sums[i] += v;
                counts[i] += 1;
            }
        }
        s += &format!(
            "  {:<30} {:>12} {:>12} {:>12} {:>12} {:>10} {:>10}   ({} train / {} test samples)\n",
            format!("mirror placement {}", r.mirror),
            cell(values[0]),
            cell(values[1]),
            cell(values[2]),
            cell(values[3]),
            cell(values[4]),
            cell(values[5]),
            r.report.train_samples,
            r.report.test_samples
        );
    }
    let mean = |i: usize| (counts[i] > 0).then(|| sums[i] / counts[i] as f64);
    s += &format!(
        "  {:<30} {:>12} {:>12} {:>12} {:>12} {:>10} {:>10}\n",
        "mean",
        cell(mean(0)),
        cell(mean(1)),
        cell(mean(2)),
        cell(mean(3)),
        cell(mean(4)),
        cell(mean(5))
    );
    s
}

fn run(args: Args) -> Result<()> {
    let text = std::fs::read_to_string(&args.config)
        .with_context(|| format!("{}: cannot read", args.config.display()))?;
    let mut config: Config = toml::from_str(&text)
        .map_err(|e| anyhow::anyhow!("{}: {}", args.config.display(), e.message()))?;
    if let Some(m) = args.mirrors {
        config.mirrors = m;
    }
    if let Some(n) = args.poses {
        config.train_poses = n;
    }
    if let Some(f) = args.fps {
        config.fps = f;
    }
    if let Some(m) = args.method {
        config.method = m;
    }
    if config.preset != "nico" || config.source != "sim" {
        bail!(
            "{}: only preset = \"nico\" with source = \"sim\" can run end to end here",
            args.config.display()
        );
    }
    config
        .method
        .parse::<Method>()
        .map_err(|e| anyhow::anyhow!("{}: key method: {e}", args.config.display()))?;
    if let Some(bad) = config.mirrors.iter().find(|m| **m > 2) {
        bail!(
            "{}: key mirrors: placement {bad} does not exist (0, 1, 2)",
            args.config.display()
        );
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create", args.out.display()))?;
    let bin_dir = std::env::current_exe()?
        .parent()
        .context("no executable directory")?
        .to_path_buf();
    let stop_flag = Arc::new(AtomicBool::new(false));
    let flag = stop_flag.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst))
        .context("installing the Ctrl-C handler")?;
    let base_prefix = args
        .prefix
        .unwrap_or_else(|| format!("run{}", std::process::id()));
    let extras = RunExtras {
        enabled: !args.no_record,
        live_view: args.live_view,
        config_path: args.config.clone(),
        trace: args.trace,
    };
    let mut results = Vec::new();
    for &m in &config.mirrors {
        let prefix = format!("{base_prefix}_m{m}");
        results.push(run_placement(
            &config, m, &args.out, &prefix, &bin_dir, &stop_flag, &extras,
        )?);
    }
    let path = args.out.join("report.json");
    let json =
        serde_json::json!({ "config": config, "paper": PAPER_FIGURES, "placements": results });
    let text = serde_json::to_string_pretty(&json)? + "\n";
    std::fs::write(&path, &text).with_context(|| format!("{}: cannot write", path.display()))?;
    if args.report == ReportFormat::Json {
        print!("{text}");
        return Ok(());
    }
    print!("{}", table(&results, &config.method));
    print!("{}", latency_table(&results));
    println!(
        "report: {}  (per placement: {}/mirror<i>/{{report.json, recording.mcap, rig.toml, plan.csv, stages.log}})",
        path.display(),
        args.out.display()
    );
    Ok(())
}

fn main() -> ExitCode {
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pipeline: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
