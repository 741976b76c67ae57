//! `recorder`: records every topic of a running pipeline into one MCAP file
//! until Ctrl-C or SIGTERM; see the crate docs and the README.

use std::net::{IpAddr, Ipv4Addr};
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
        live_view: args
            .live_view
            .map(|port| (live_view_address(args.live_view_bind), port)),
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

/// Where the live view listens: localhost unless `bind` says, which is
/// then a warning (the Foxglove protocol has no authentication).
fn live_view_address(bind: Option<IpAddr>) -> String {
    match bind {
        Some(address) if !address.is_loopback() => {
            tracing::warn!(
                "the live view listens on {address}: anyone who reaches it sees the run's images, \
                 poses and calibration (the Foxglove protocol has no authentication)"
            );
            address.to_string()
        }
        Some(address) => address.to_string(),
        None => Ipv4Addr::LOCALHOST.to_string(),
    }
}

fn main() -> ExitCode {
    runtime::stage_main("recorder", || run(Args::parse()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_live_view_stays_on_localhost_unless_told() {
        assert_eq!(live_view_address(None), "127.0.0.1");
        assert_eq!(live_view_address(Some("::1".parse().unwrap())), "::1");
        assert_eq!(
            live_view_address(Some("0.0.0.0".parse().unwrap())),
            "0.0.0.0"
        );
    }
}
