//! `tracker_proc`: finds ArUco markers, normal and mirror-reversed, in
//! stereo frames (`run`) or in image files (`detect`).

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Result, bail};
use clap::{Parser, Subcommand};
use messages::{now_ns, topics};
use opencv::prelude::*;
use tracker_proc::{Detector, Tracked, Tracker};

/// Track ArUco markers, including markers seen in a mirror.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Subscribe to stereo frames and publish detections.
    Run(stages::tracker::Args),
    /// Print each image's detections as JSON lines (id, mirrored, corners, center).
    Detect {
        /// Image files.
        #[arg(required = true)]
        images: Vec<PathBuf>,
    },
}

fn detect_files(images: &[PathBuf]) -> Result<()> {
    // Our own error names the file; OpenCV's warning would be a second line.
    opencv::core::set_log_level(opencv::core::LogLevel::LOG_LEVEL_SILENT)?;
    let mut detector = Detector::new(true)?;
    for path in images {
        let image = opencv::imgcodecs::imread(
            path.to_string_lossy().to_string(),
            opencv::imgcodecs::IMREAD_GRAYSCALE,
        )?;
        if image.empty() {
            bail!("{}: cannot read or decode the image", path.display());
        }
        for m in detector.detect(&image)? {
            let corners: Vec<[f64; 2]> = m.corners.chunks(2).map(|c| [c[0], c[1]]).collect();
            let line = serde_json::json!({
                "image": path.display().to_string(),
                "id": m.id,
                "mirrored": m.mirrored == 1,
                "corners": corners,
                "center": m.center,
            });
            println!("{line}");
        }
    }
    Ok(())
}

fn run(prefix: &str, mirrored: bool, full_scan_every: u32) -> Result<()> {
    let mut tracker = Tracker::with_full_scan_every(mirrored, full_scan_every)?;
    let bus = stages::bus_of::<stages::tracker::Tracker>(prefix)?;
    let frames = bus.frame_subscriber::<topics::Frames>()?;
    let publisher = bus.publisher::<topics::Detections>()?;
    let mut stats = runtime::stats::StageStats::new("tracker_proc");
    let mut count = 0u64;
    tracing::info!(mirrored, full_scan_every, "tracking");
    bus.wake()?
        .run(&[frames.listener()], None, || -> Result<_> {
            loop {
                let received_ns = now_ns();
                let cpu = runtime::stats::StepStart::now();
                // Detections go out first; the periodic full scan of the
                // same frame follows, before the frame is let go.
                let step = |h: &messages::FrameHeader, payload: &[u8]| -> Result<()> {
                    let whole_before = tracker.scans().0;
                    if let Tracked::Detections(det) = tracker.step(h, payload)? {
                        publisher.send(det)?;
                        let now = now_ns();
                        stats.record("receive_to_publish", now - received_ns);
                        // Frames an image of which was searched whole before
                        // the detections went out: the latency's tail.
                        if tracker.scans().0 > whole_before {
                            stats.record("receive_to_publish_whole", now - received_ns);
                        } else {
                            stats.record("receive_to_publish_windows", now - received_ns);
                        }
                        stats.record("capture_to_publish", now - det.stamp_ns);
                        count += 1;
                    }
                    tracker.catch_up(h, payload)?;
                    Ok(())
                };
                let Some(stepped) = frames.receive_with(step)? else {
                    return Ok(ControlFlow::Continue(()));
                };
                stepped?;
                stats.cpu_step(cpu);
            }
        })?;
    stats.count("frames_missed", tracker.frames_missed());
    stats.count("rejected", tracker.rejected());
    let (full, windows) = tracker.scans();
    stats.count("images_scanned_whole", full);
    stats.count("images_scanned_by_windows", windows);
    stats.finish();
    tracing::info!(
        frames = count,
        rejected = tracker.rejected(),
        "tracker stopped"
    );
    Ok(())
}

fn main() -> ExitCode {
    runtime::stage_main("tracker_proc", || match Args::parse().command {
        Command::Run(args) => run(&args.prefix, !args.no_mirrored, args.full_scan_every),
        Command::Detect { images } => detect_files(&images),
    })
}
