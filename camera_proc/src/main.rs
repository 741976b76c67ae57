//! `camera_proc`: publishes stereo frames into shared memory, written in
//! place by the renderer or the decoder.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use camera_proc::render::{Facing, Renderer, SimWorld};
use camera_proc::source::{Captures, ImagePairs, StereoSource};
use clap::{Parser, Subcommand};
use messages::{Bus, FrameHeader, JointState, encoding, now_ns, phase, topics};
use opencv::core::{Mat, Vector};

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
    Sim {
        /// Service prefix of the pipeline.
        #[arg(long, default_value = "default")]
        prefix: String,
        /// Mirror placement of the Nico scene (0, 1, 2).
        #[arg(long, default_value_t = 0)]
        mirror: usize,
        /// Frame rate, Hz.
        #[arg(long, default_value_t = 30.0)]
        fps: f64,
        /// Frames to keep rendering after the pose plan is done.
        #[arg(long, default_value_t = 5)]
        tail_frames: u32,
    },
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
        /// Output prefix: writes PREFIX_left.png and PREFIX_right.png.
        #[arg(long)]
        out: PathBuf,
    },
}

fn header(seq: u64, width: u32, height: u32) -> FrameHeader {
    FrameHeader {
        seq,
        stamp_ns: now_ns(),
        published_ns: 0,
        width,
        height,
        stride: width,
        encoding: encoding::MONO8,
    }
}

fn run_sim(prefix: &str, mirror: usize, fps: f64, tail_frames: u32) -> Result<()> {
    if !(fps > 0.0 && fps <= 1000.0) {
        bail!("--fps must be in (0, 1000]");
    }
    let world = SimWorld::nico(mirror)?;
    let intr = world.rig.cameras[0].intrinsics;
    let dof = world.rig.arm.as_ref().map_or(0, |a| a.dof());
    let mut renderer = Renderer::new(world)?;
    let bus = Bus::new(prefix, "camera_proc")?;
    let frames = bus.frame_publisher(topics::FRAMES, 2 * (intr.width * intr.height) as usize)?;
    let joints = bus.subscriber::<JointState>(topics::JOINT_STATE)?;
    let mut latest: Option<JointState> = None;
    let mut rejections = messages::Rejections::default();
    let mut order = messages::StampOrder::default();
    let (mut seq, mut after_done) = (0u64, 0u32);
    let period_ns = (1e9 / fps) as i64;
    let mut next_due = i64::MIN;
    let (mut last_published, mut late) = (None::<i64>, 0u64);
    let mut failure = None;
    let mut stats = messages::stats::StageStats::new("camera_proc");
    tracing::info!(mirror, fps, "rendering the simulated head");
    // A fine tick keeps frames within a millisecond of their schedule.
    let tick = Duration::from_nanos(period_ns as u64).min(Duration::from_millis(1));
    bus.wake()?.run(&[joints.listener()], Some(tick), || {
        loop {
            match joints.receive() {
                // A bad joint state would render nonsense or fail the
                // render: dropped, and the last good pose kept.
                Ok(Some(s)) => match s.fault(dof).map_or_else(|| order.check(s.stamp_ns), Err) {
                    Err(why) => rejections.reject("joint state", s.seq, &why),
                    Ok(()) => latest = Some(s),
                },
                Ok(None) => break,
                Err(e) => {
                    failure = Some(anyhow::Error::from(e));
                    return false;
                }
            }
        }
        let Some(state) = latest else { return true };
        // Render on the frame clock only; joint-state wake-ups just update the pose.
        let now = now_ns();
        if next_due == i64::MIN {
            next_due = now;
        }
        if now < next_due {
            return true;
        }
        // A whole period behind schedule (rendering too slow for the
        // frame rate): count the frames that could not be made.
        let behind = (now - next_due) / period_ns;
        if behind > 0 {
            late += behind as u64;
            next_due = now;
        }
        next_due += period_ns;
        let h = header(seq, intr.width, intr.height);
        let _span = tracing::trace_span!("camera_step", seq).entered();
        match frames.publish(h, |left, right| {
            renderer
                .render(state.joints(), facing(state.role), seq, left, right)
                .map(|_| ())
        }) {
            // The simulated capture: the frame's stamp to its publication (rendering).
            Ok(Ok(())) => {
                let published = now_ns();
                stats.record("capture_to_publish", published - h.stamp_ns);
                if let Some(last) = last_published {
                    stats.record("frame_interval", published - last);
                }
                last_published = Some(published);
            }
            Ok(Err(e)) => {
                failure = Some(e);
                return false;
            }
            Err(e) => {
                failure = Some(e.into());
                return false;
            }
        }
        seq += 1;
        if state.phase == phase::DONE {
            after_done += 1;
        }
        after_done <= tail_frames
    })?;
    stats.count("frames", seq);
    stats.count("frames_late", late);
    stats.count("joint_states_rejected", rejections.count());
    stats.finish();
    if let Some(e) = failure {
        return Err(e);
    }
    tracing::info!(frames = seq, "camera done");
    Ok(())
}

/// Direct test poses turn the card to the head; all others to the mirror.
fn facing(role: u32) -> Facing {
    if role == messages::role::DIRECT {
        Facing::Head
    } else {
        Facing::Mirror
    }
}

fn run_source(prefix: &str, mut source: impl StereoSource, fps: Option<f64>) -> Result<()> {
    let (w, h) = source.size();
    let bus = Bus::new(prefix, "camera_proc")?;
    let frames = bus.frame_publisher(topics::FRAMES, 2 * (w * h) as usize)?;
    let mut seq = 0u64;
    let mut more = true;
    let mut failure = None;
    let tick = fps
        .map(|f| Duration::from_secs_f64(1.0 / f))
        .unwrap_or(Duration::from_millis(1));
    bus.wake()?.run(&[], Some(tick), || {
        let result = frames.publish(header(seq, w, h), |left, right| {
            source.next_into(left, right).map(|m| more = m)
        });
        match result {
            Ok(Ok(())) => {}
            Ok(Err(e)) => failure = Some(e),
            Err(e) => failure = Some(e.into()),
        }
        seq += 1;
        failure.is_none() && more
    })?;
    failure.map_or(Ok(()), Err)
}

fn snapshot(mirror: usize, q: &[f64], facing: Facing, out: &std::path::Path) -> Result<()> {
    let world = SimWorld::nico(mirror)?;
    let intr = world.rig.cameras[0].intrinsics;
    let dof = world.rig.arm.as_ref().map_or(0, |a| a.dof());
    if q.len() != dof {
        bail!("--q: {} joint angles given, the arm has {dof}", q.len());
    }
    let mut renderer = Renderer::new(world)?;
    let n = (intr.width * intr.height) as usize;
    let (mut left, mut right) = (vec![0u8; n], vec![0u8; n]);
    let truth = renderer.render(q, facing, 0, &mut left, &mut right)?;
    for (side, data, markers) in [
        ("left", &mut left, &truth.markers[0]),
        ("right", &mut right, &truth.markers[1]),
    ] {
        let path = PathBuf::from(format!("{}_{side}.png", out.display()));
        let mat = Mat::new_rows_cols_with_data_mut(
            intr.height as i32,
            intr.width as i32,
            data.as_mut_slice(),
        )?;
        opencv::imgcodecs::imwrite(&path, &mat, &Vector::new())
            .with_context(|| format!("{}: cannot write", path.display()))?;
        let drawn: Vec<String> = markers
            .iter()
            .map(|m| format!("id {}{}", m.0, if m.1 { " (mirrored)" } else { "" }))
            .collect();
        println!(
            "{}: {}",
            path.display(),
            if drawn.is_empty() {
                "no markers".into()
            } else {
                drawn.join(", ")
            }
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    messages::stage_main("camera_proc", || match Args::parse().source {
        Source::Sim {
            prefix,
            mirror,
            fps,
            tail_frames,
        } => run_sim(&prefix, mirror, fps, tail_frames),
        Source::Files { prefix, dir, fps } => {
            ImagePairs::open(&dir).and_then(|s| run_source(&prefix, s, Some(fps)))
        }
        Source::Device {
            prefix,
            source,
            right,
        } => match right {
            Some(r) => Captures::pair(&source, &r).and_then(|s| run_source(&prefix, s, None)),
            None => Captures::side_by_side(&source).and_then(|s| run_source(&prefix, s, None)),
        },
        Source::Snapshot {
            mirror,
            q,
            direct,
            out,
        } => snapshot(
            mirror,
            &q,
            if direct { Facing::Head } else { Facing::Mirror },
            &out,
        ),
    })
}
