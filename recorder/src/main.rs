//! `recorder`: records every topic of a running pipeline into one MCAP file
//! until Ctrl-C or SIGTERM; see the crate docs and the README.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Result;
use clap::Parser;
use recorder::writer::{Compression, WriterOptions};
use recorder::{RecordOptions, record};

/// Record a running pipeline into an MCAP file (until Ctrl-C / SIGTERM).
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    /// Service prefix of the pipeline to record.
    #[arg(long)]
    prefix: String,
    /// Output file.
    #[arg(long, default_value = "recording.mcap")]
    out: PathBuf,
    /// Replace the output file if it exists.
    #[arg(long)]
    overwrite: bool,
    /// Chunk compression.
    #[arg(long, value_enum, default_value_t = Compression::Zstd)]
    compression: Compression,
    /// Rig TOML: enables camera calibrations, camera frames and the arm in
    /// the viewing channels, and is stored as metadata and an attachment.
    #[arg(long)]
    rig: Option<PathBuf>,
    /// More files to attach (the pose plan, the pipeline config, ...).
    #[arg(long)]
    attach: Vec<PathBuf>,
    /// Extra metadata, KEY=VALUE (stored in the `run` metadata record).
    #[arg(long, value_parser = parse_key_value)]
    meta: Vec<(String, String)>,
    /// Wait for the writer instead of dropping frames when it falls behind.
    #[arg(long)]
    no_drop: bool,
    /// Frames queued for the writer at most.
    #[arg(long, default_value_t = 64)]
    frame_queue: usize,
    /// Leave out the viewing image channels (the frames stay in the lossless channel).
    #[arg(long)]
    no_view_images: bool,
    /// Finish a chunk at least this often, ms (what a crash can lose).
    #[arg(long, default_value_t = 1000)]
    flush_ms: u64,
    /// Also serve the viewing channels live to Foxglove over WebSocket on this port of localhost.
    #[arg(long)]
    live_view: Option<u16>,
    /// SCHED_FIFO priority (1-99) of the thread that takes messages out of
    /// shared memory, when the stages publishing them run at real-time
    /// priority (the launcher passes its base priority); compression and
    /// writing keep the process's priority.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=99))]
    realtime_priority: Option<u8>,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    json: bool,
}

fn parse_key_value(s: &str) -> Result<(String, String), String> {
    s.split_once('=')
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .ok_or_else(|| format!("`{s}`: expected KEY=VALUE"))
}

fn run(args: Args) -> Result<()> {
    if args.out.exists() && !args.overwrite {
        anyhow::bail!(
            "{}: exists; pass --overwrite to replace it",
            args.out.display()
        );
    }
    let mut writer = WriterOptions {
        compression: args.compression,
        flush_every: Duration::from_millis(args.flush_ms.max(1)),
        frame_queue: args.frame_queue,
        view_images: !args.no_view_images,
        ..Default::default()
    };
    writer.describe_run(&args.prefix, args.meta);
    let rig = args
        .rig
        .as_deref()
        .map(|path| writer.attach_rig(path))
        .transpose()?;
    for path in &args.attach {
        writer.attach(path);
    }
    let options = RecordOptions {
        writer,
        rig,
        live_view: args.live_view.map(|p| ("127.0.0.1".to_string(), p)),
        drop_frames: !args.no_drop,
        realtime_priority: args.realtime_priority,
    };
    let summary = record(&args.prefix, &args.out, options)?;
    summary.write_stats();
    tracing::info!(
        file = %summary.path.display(),
        bytes = summary.file_bytes,
        frames_dropped = summary.frames_dropped_queue_full,
        frames_missed = summary.frames_missed,
        "recording finished"
    );
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    }
    Ok(())
}

fn main() -> ExitCode {
    messages::stage_main("recorder", || run(Args::parse()))
}
