//! `camera_proc`: publishes stereo frames into shared memory, written in
//! place by the renderer or the decoder.

use std::path::PathBuf;
use std::process::ExitCode;

use camera_proc::source::{Captures, ImagePairs};
use camera_proc::stage::{self, Pace};
use clap::{Parser, Subcommand};
use geometry::sim::Facing;
use renderer::look::LookName;

/// Publish synchronized stereo frames.
#[derive(Debug, Parser)]
#[command(version, about)]
struct Args {
    #[command(subcommand)]
    source: Source,
}

#[derive(Debug, Subcommand)]
enum Source {
    /// Render what the simulated head sees, following the arm's joint states.
    Sim(stages::camera::Args),
    /// Play a directory of image pairs (`*left*` / `*right*`).
    Files {
        /// Service prefix of the pipeline.
        #[arg(long, default_value = "default")]
        prefix: String,
        /// The directory.
        dir: PathBuf,
        /// Frame rate, Hz.
        #[arg(long, default_value_t = 30.0)]
        fps: f64,
        /// Instead of a rate: wait for N frame subscribers (the tracker, the
        /// recorder), then publish each pair as soon as all have room, so
        /// none is lost. Start this stage before its subscribers.
        #[arg(long, value_name = "N", conflicts_with = "fps")]
        lockstep: Option<usize>,
    },
    /// Capture from a side-by-side stereo device or video file, or two devices.
    Device {
        /// Service prefix of the pipeline.
        #[arg(long, default_value = "default")]
        prefix: String,
        /// Device or file (`/dev/video0`, `stereo.mp4`); side by side unless --right is given.
        source: String,
        /// Right camera device, when the cameras are separate.
        #[arg(long)]
        right: Option<String>,
        /// Play a video file at this rate, Hz (default: the file's own rate;
        /// a live device always delivers at its own).
        #[arg(long)]
        fps: Option<f64>,
        /// Play a video file in lockstep instead of at a rate: wait for N
        /// frame subscribers (the tracker, the recorder), then publish each
        /// pair as soon as all have room, so none is lost. Start this stage
        /// before its subscribers.
        #[arg(long, value_name = "N", conflicts_with = "fps")]
        lockstep: Option<usize>,
    },
    /// Render one stereo pair of the simulated scene to PNG files (debugging).
    Snapshot {
        /// Mirror placement (0, 1, 2).
        #[arg(long, default_value_t = 0)]
        mirror: usize,
        /// Encoder readings, comma separated, rad.
        #[arg(long, value_delimiter = ',', required = true)]
        q: Vec<f64>,
        /// Turn the arm's card to the head (a direct view) instead of the mirror.
        #[arg(long)]
        direct: bool,
        /// What the images look like.
        #[arg(long, value_enum, default_value_t = LookName::Realistic)]
        look: LookName,
        /// Output prefix: writes PREFIX_left.png and PREFIX_right.png.
        #[arg(long)]
        out: PathBuf,
    },
}

fn run(args: Args) -> anyhow::Result<()> {
    match args.source {
        Source::Sim(stages::camera::Args {
            prefix,
            mirror,
            fps,
            tail_frames,
            look,
            mjpeg,
            changes,
        }) => {
            let look = renderer::look::Look {
                jpeg_quality: mjpeg,
                ..renderer::look::Look::named(look)
            };
            stage::run_sim(&prefix, mirror, fps, tail_frames, look, &changes)?;
        }
        Source::Files {
            prefix,
            dir,
            fps,
            lockstep,
        } => {
            let pace = match lockstep {
                Some(subscribers) => Pace::Lockstep { subscribers },
                None => Pace::Rate(fps),
            };
            stage::run_source(&prefix, ImagePairs::open(&dir)?, pace)?;
        }
        Source::Device {
            prefix,
            source,
            right,
            fps,
            lockstep,
        } => {
            let captures = match right {
                Some(r) => Captures::pair(&source, &r)?,
                None => Captures::side_by_side(&source)?,
            };
            if let Some(f) = fps
                && !(f > 0.0 && f <= 1000.0)
            {
                anyhow::bail!("--fps must be in (0, 1000]");
            }
            // A file plays at --fps or its own rate, or in lockstep; a
            // device at its own rate.
            let pace = match (captures.file_rate(), lockstep) {
                (None, Some(_)) => anyhow::bail!(
                    "--lockstep needs a video file: a live device delivers at its own rate"
                ),
                (Some(_), Some(subscribers)) => Pace::Lockstep { subscribers },
                (Some(own), None) => Pace::Rate(fps.unwrap_or(own)),
                (None, None) => Pace::AsDelivered,
            };
            tracing::info!(?pace, "playing");
            stage::run_source(&prefix, captures, pace)?;
        }
        Source::Snapshot {
            mirror,
            q,
            direct,
            look,
            out,
        } => camera_proc::snapshot::snapshot(
            mirror,
            &q,
            if direct { Facing::Head } else { Facing::Mirror },
            look,
            &out,
        )?,
    }
    Ok(())
}

fn main() -> ExitCode {
    runtime::stage_main("camera_proc", || run(Args::parse()))
}
