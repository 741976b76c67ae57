//! `replay`: publishes a recording back onto the bus; see the crate docs.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Result, bail};
use clap::{Parser, Subcommand};
use recorder::reader::Recording;
use recorder::replay::{ReplayBus, ReplayOptions, replay};
use stages::replay::Args;

/// Publish a recording back onto a pipeline's topics, or compare two
/// recordings (`replay diff A B`).
///
/// Start replay first (it creates the services, lossless), then the stages
/// to re-run on the same --prefix: `--kind frames` re-runs tracker_proc and
/// mirror_proc, `--kind detections` re-runs mirror_proc only (`pipeline
/// --replay FILE` does all of it).
#[derive(Debug, Parser)]
#[command(
    version,
    about,
    long_about = None,
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    replay: Args,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Compare two recordings channel by channel: counts, the first message
    /// that differs and in which fields, and numeric deltas of the typed
    /// messages. Exit 0 when the compared channels are identical, 1 when
    /// they differ, 2 on error.
    Diff {
        /// The first recording.
        a: PathBuf,
        /// The second recording.
        b: PathBuf,
        /// Compare only these channels (comma separated), e.g. calibration,samples.
        #[arg(long, value_delimiter = ',')]
        channels: Option<Vec<String>>,
        /// Print the comparison as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Write a recording as a ROS 2 bag (rosbag2, MCAP storage) for `ros2
    /// bag play` and rosbag2 readers: /joint_states, the images and camera
    /// infos, /tf_static and the located objects, on wall-clock time.
    Export {
        /// The recording.
        file: PathBuf,
        /// The bag directory to create (metadata.yaml and DIR_0.mcap).
        #[arg(long, value_name = "DIR", required = true)]
        ros2: PathBuf,
    },
}

fn run(args: Args) -> Result<()> {
    let topics = args.published().to_vec();
    // clap requires both unless a subcommand is given.
    let (Some(file), Some(prefix)) = (&args.file, &args.prefix) else {
        bail!("give the recording and --prefix");
    };
    Recording::probe(file)?;
    let recording = Recording::open(file)?;
    let bus = ReplayBus::create(prefix, &recording, &topics)?;
    tracing::info!(
        prefix = prefix.as_str(),
        "services created; start the stages to re-run"
    );
    let contents = recording.contents();
    if let Some(d) = &contents.damage {
        tracing::warn!(
            "{}: damaged after {} messages ({}); replaying the readable part",
            file.display(),
            d.after_messages,
            d.error
        );
    }
    for t in &topics {
        if contents.counts.get(t).copied().unwrap_or(0) == 0 {
            tracing::warn!(
                topic = t.name(),
                "the recording has no messages on this topic"
            );
        }
    }
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))?;
    }
    let options = ReplayOptions {
        pace: args.pace,
        start_s: args.start,
        wait_subscribers: args.wait_subscribers,
        wait_timeout: seconds("--wait-timeout", args.wait_timeout)?,
        progress: std::io::stderr().is_terminal(),
    };
    let stats = replay(&bus, &recording, &options, &|| stop.load(Ordering::SeqCst))?;
    tracing::info!(
        published = stats.published,
        recorded_s = stats.recorded_seconds,
        wall_s = stats.wall_seconds,
        speed = stats.speed(),
        "replay done"
    );
    if let Some(why) = &stats.stopped_early {
        tracing::warn!("{why}");
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&stats)?);
    }
    Ok(())
}

/// A duration given in seconds on the command line.
fn seconds(flag: &str, s: f64) -> Result<Duration> {
    Duration::try_from_secs_f64(s)
        .map_err(|_| anyhow::anyhow!("{flag}: `{s}` is not a number of seconds >= 0"))
}

/// `replay diff`: the report on stdout; exit 0 identical, 1 different, 2 error.
fn diff(a: &Path, b: &Path, channels: Option<&[String]>, json: bool) -> ExitCode {
    match recorder::diff::diff(a, b, channels) {
        Ok(report) => {
            if json {
                match serde_json::to_string_pretty(&report) {
                    Ok(text) => println!("{text}"),
                    Err(e) => {
                        eprintln!("replay: error: {e}");
                        return ExitCode::from(2);
                    }
                }
            } else {
                print!("{}", recorder::diff::table(&report));
            }
            if report.identical {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(1)
            }
        }
        Err(e) => {
            eprintln!("replay: error: {e}");
            ExitCode::from(2)
        }
    }
}

/// `replay export --ros2`: the bag, and what went into it on stdout.
fn export(file: &Path, out: &Path) -> Result<()> {
    Recording::probe(file)?;
    let recording = Recording::open(file)?;
    let exported = recorder::ros2_export::export_ros2(&recording, out)?;
    if exported.wall_minus_monotonic_ns.is_none() {
        tracing::warn!(
            "{}: no wall-clock offset recorded (an older recorder); stamps stay on the recording host's monotonic clock",
            file.display()
        );
    }
    println!("{}", exported.file.display());
    for (topic, n) in &exported.topics {
        println!("  {topic}: {n}");
    }
    for (topic, n) in &exported.not_exported {
        println!("  not exported (no ROS type): {topic}: {n}");
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Export { file, ros2 }) => {
            runtime::stage_main("replay", || export(&file, &ros2))
        }
        Some(Command::Diff {
            a,
            b,
            channels,
            json,
        }) => diff(&a, &b, channels.as_deref(), json),
        None => runtime::stage_main("replay", || run(cli.replay)),
    }
}
