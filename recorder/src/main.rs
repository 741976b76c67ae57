//! `recorder`: records every topic of a running pipeline into one MCAP file
//! until Ctrl-C or SIGTERM; see the crate docs and the README.

use std::process::ExitCode;
use std::time::Duration;

use anyhow::Result;
use clap::Parser;
use recorder::writer::WriterOptions;
use recorder::{RecordOptions, record};
use stages::recorder::Args;

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
    runtime::stage_main("recorder", || run(Args::parse()))
}
