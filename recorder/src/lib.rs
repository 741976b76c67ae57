//! Recording and replay of the pipeline in MCAP.
//!
//! - [`record`] subscribes to every topic of a pipeline and writes one MCAP
//!   file: lossless channels ([`channels`]) with the exact message bytes and
//!   a layout schema, and viewing channels ([`view`]) in Foxglove's schemas,
//!   chunked, compressed, indexed, with metadata and attachments. A writer
//!   thread ([`writer`]) finishes a chunk at least once a second.
//! - [`reader::Recording`] reads one back, refusing layouts this build does
//!   not know and stopping cleanly at damage.
//! - [`replay::replay`] publishes it onto the bus again;
//!   [`ros2_export::export_ros2`] writes it as a ROS 2 bag.
//! - [`live_view::LiveView`] serves the viewing channels over the Foxglove
//!   WebSocket protocol while the pipeline runs.
//!
//! ```no_run
//! use recorder::reader::Recording;
//! let recording = Recording::open("out/pipeline/mirror0/recording.mcap")?;
//! println!("{} lossless messages", recording.contents().total());
//! # Ok::<(), recorder::reader::ReadError>(())
//! ```

pub mod capture;
pub mod channels;
pub mod diff;
pub mod live_view;
pub mod reader;
pub mod replay;
pub mod ros2_export;
pub mod view;
pub mod writer;

use std::ops::ControlFlow;
use std::path::Path;
use std::time::Duration;

use runtime::{Bus, BusError};

use crate::capture::{Capture, CaptureError};
use crate::live_view::{LiveView, LiveViewError};
use crate::view::ViewBuilder;
use crate::writer::{RecordingSummary, WriterError, WriterOptions};

/// How [`record`] runs.
pub struct RecordOptions {
    /// The writer's settings.
    pub writer: WriterOptions,
    /// The rig, for camera calibrations, camera frames and the arm.
    pub rig: Option<geometry::Rig>,
    /// Serve the live view on this `host:port`.
    pub live_view: Option<(String, u16)>,
    /// Drop frames (counted) when the writer falls behind, instead of
    /// waiting for it (which holds up the camera only on lossless buses).
    pub drop_frames: bool,
    /// `SCHED_FIFO` priority of the thread that takes messages out of
    /// shared memory; `None`: the process's scheduling. Stages at real-time
    /// priority can keep a normally scheduled recorder off both cores for
    /// longer than a subscriber holds frames (4); the copying is cheap, and
    /// compressing and writing stay on the writer thread at the process's
    /// priority, with the frame queue to take up their delay.
    pub realtime_priority: Option<u8>,
}

/// Why [`record`] failed.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// Opening the bus, its subscribers or its waitset failed.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The live view could not start.
    #[error(transparent)]
    LiveView(#[from] LiveViewError),
    /// The writer could not start.
    #[error(transparent)]
    Writer(#[from] WriterError),
    /// The writer failed while recording (its error says why).
    #[error("recording stopped")]
    WriterStopped(#[source] WriterError),
    /// Taking messages from shared memory failed while recording.
    #[error("recording stopped")]
    CaptureStopped(#[source] CaptureError),
}

/// Records pipeline `prefix` into `path` until SIGINT/SIGTERM, then takes
/// what is still waiting, finishes the file and returns its summary.
pub fn record(
    prefix: &str,
    path: &Path,
    options: RecordOptions,
) -> Result<RecordingSummary, RecordError> {
    let bus = Bus::new(prefix, "recorder")?;
    let capture = Capture::new(&bus)?;
    let live = match &options.live_view {
        Some((host, port)) => {
            let live = LiveView::start(host, *port)?;
            tracing::info!(
                port = live.port(),
                "live view: connect Foxglove to ws://{host}:{}",
                live.port()
            );
            Some(live)
        }
        None => None,
    };
    let handle = writer::start(
        path,
        options.writer,
        ViewBuilder::new(options.rig),
        live,
        options.drop_frames,
    )?;
    tracing::info!(prefix, path = %path.display(), "recording");
    // Only now: the writer (and live view) threads started above keep the
    // process's scheduling.
    if let Some(priority) = options.realtime_priority
        && let Err(e) = runtime::realtime::fifo_this_thread(priority)
    {
        tracing::warn!(
            priority,
            "receiving at normal priority: real-time priority not allowed ({e})"
        );
    }
    let captured = bus.wake()?.run(
        &capture.listeners(),
        Some(Duration::from_millis(250)),
        || capture.drain(&handle).map(|_| ControlFlow::Continue(())),
    );
    // The writer's own error says more than the capture's "writer stopped".
    match (handle.finish(), captured) {
        (Ok(summary), Ok(())) => Ok(summary),
        (Err(e), _) => Err(RecordError::WriterStopped(e)),
        (Ok(_), Err(e)) => Err(RecordError::CaptureStopped(e)),
    }
}
