//! `tracker_proc`: finds ArUco markers, normal and mirror-reversed, in
//! stereo frames (`run`) or in image files (`detect`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Result, bail};
use clap::{Parser, Subcommand};
use messages::{Bus, CameraMarkers, StereoDetections, now_ns, topics};
use opencv::core::Mat;
use opencv::prelude::*;
use tracker_proc::Detector;

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
    Run {
        /// Service prefix of the pipeline.
        #[arg(long, default_value = "default")]
        prefix: String,
        /// Only find markers as printed (no mirror-reversed ones).
        #[arg(long)]
        no_mirrored: bool,
    },
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

fn run(prefix: &str, mirrored: bool) -> Result<()> {
    let mut detector = Detector::new(mirrored)?;
    let bus = Bus::new(prefix, "tracker_proc")?;
    let frames = bus.frame_subscriber(topics::FRAMES)?;
    let publisher = bus.publisher::<StereoDetections>(topics::DETECTIONS)?;
    let mut count = 0u64;
    let mut rejections = messages::Rejections::default();
    let mut order = messages::StampOrder::default();
    let mut last_seq: Option<u64> = None;
    let mut stats = messages::stats::StageStats::new("tracker_proc");
    stats.count("frames_missed", 0);
    let mut failure = None;
    tracing::info!(mirrored, "tracking");
    bus.wake()?.run(&[frames.listener()], None, || {
        loop {
            let received_ns = now_ns();
            let step = frames.receive_with(|header, payload| -> Result<Option<StereoDetections>> {
                let _span = tracing::trace_span!("tracker_step", seq = header.seq).entered();
                if let Err(why) = header.validate(payload.len()) {
                    rejections.reject("frame", header.seq, &why);
                    return Ok(None);
                }
                if let Err(why) = order.check(header.stamp_ns) {
                    rejections.reject("frame", header.seq, &why);
                    return Ok(None);
                }
                // Frames overwritten in shared memory before we took them
                // (counted among the frames we could use).
                if let Some(last) = last_seq
                    && header.seq > last + 1
                {
                    stats.count("frames_missed", header.seq - last - 1);
                }
                last_seq = Some(header.seq);
                let channels = header.bytes_per_pixel().unwrap_or(1) as i32;
                let mut out = StereoDetections {
                    seq: header.seq,
                    stamp_ns: header.stamp_ns,
                    frame_published_ns: header.published_ns,
                    ..Default::default()
                };
                for (k, image) in payload.chunks_exact(header.image_len()).enumerate().take(2) {
                    // A Mat header over the shared-memory image: no copy.
                    let flat = Mat::new_rows_cols_with_data(
                        header.height as i32,
                        header.stride as i32,
                        image,
                    )?;
                    let view = flat.reshape(channels, header.height as i32)?;
                    let roi = Mat::roi(
                        &view,
                        opencv::core::Rect::new(0, 0, header.width as i32, header.height as i32),
                    )?;
                    let mut markers = CameraMarkers::default();
                    for m in detector.detect(&roi)? {
                        markers.push(m);
                    }
                    out.cameras[k] = markers;
                }
                Ok(Some(out))
            });
            match step {
                Ok(Some(Ok(Some(det)))) => {
                    if let Err(e) = publisher.send(det) {
                        failure = Some(e.into());
                        return false;
                    }
                    let now = now_ns();
                    stats.record("receive_to_publish", now - received_ns);
                    stats.record("capture_to_publish", now - det.stamp_ns);
                    count += 1;
                }
                Ok(Some(Ok(None))) => {}
                Ok(Some(Err(e))) => {
                    failure = Some(e);
                    return false;
                }
                Ok(None) => return true,
                Err(e) => {
                    failure = Some(e.into());
                    return false;
                }
            }
        }
    })?;
    stats.count("rejected", rejections.count());
    stats.finish();
    tracing::info!(
        frames = count,
        rejected = rejections.count(),
        "tracker stopped"
    );
    failure.map_or(Ok(()), Err)
}

fn main() -> ExitCode {
    messages::stage_main("tracker_proc", || match Args::parse().command {
        Command::Run {
            prefix,
            no_mirrored,
        } => run(&prefix, !no_mirrored),
        Command::Detect { images } => detect_files(&images),
    })
}
