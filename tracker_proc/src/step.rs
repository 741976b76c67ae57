//! The tracker's per-frame step: a frame header and its pixels in shared
//! memory in, detections or a counted rejection out. The stage's loop only
//! moves frames and detections between the bus and this step.

use messages::{CameraMarkers, FrameHeader, StereoDetections};
use opencv::boxed_ref::BoxedRef;
use opencv::core::{Mat, Rect};
use opencv::prelude::*;
use runtime::{Rejections, StampOrder};

use crate::regions::RegionTracker;
use crate::{Detector, Result, TrackError};

/// Frames between full scans of an image by default (a third of a second
/// at 30 fps); see [`RegionTracker`].
pub const FULL_SCAN_EVERY: u32 = 10;

/// What one frame gave.
// One per frame, handed straight on: boxing the detections would allocate per frame.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Tracked {
    /// The markers found in both images.
    Detections(StereoDetections),
    /// The frame was dropped (malformed, or stamped out of order), and why;
    /// it is counted in [`Tracker::rejected`] and logged at a limited rate.
    Rejected(String),
}

/// One camera's detector and region tracking.
struct Camera {
    detector: Detector,
    regions: RegionTracker,
}

impl Camera {
    /// Runs `f` on one image of a frame, read in place through a `Mat`
    /// header over the shared-memory pixels: no copy.
    fn with_image<R>(
        &mut self,
        header: &FrameHeader,
        image: &[u8],
        f: impl FnOnce(&mut Self, &BoxedRef<'_, Mat>) -> Result<R>,
    ) -> Result<R> {
        let channels = header.bytes_per_pixel().unwrap_or(1) as i32;
        let flat = Mat::new_rows_cols_with_data(header.height as i32, header.stride as i32, image)?;
        let view = flat.reshape(channels, header.height as i32)?;
        let roi = Mat::roi(
            &view,
            Rect::new(0, 0, header.width as i32, header.height as i32),
        )?;
        f(self, &roi)
    }

    /// The markers of one image of a frame.
    fn track(&mut self, header: &FrameHeader, image: &[u8]) -> Result<CameraMarkers> {
        self.with_image(header, image, |camera, roi| {
            let mut markers = CameraMarkers::default();
            for m in camera.regions.detect(&mut camera.detector, roi)?.0 {
                markers.push(m);
            }
            Ok(markers)
        })
    }

    /// The periodic full scan of the image last tracked, if it is due.
    fn catch_up(&mut self, header: &FrameHeader, image: &[u8]) -> Result<()> {
        if self.regions.due() {
            self.with_image(header, image, |camera, roi| {
                camera.regions.catch_up(&mut camera.detector, roi)
            })?;
        }
        Ok(())
    }
}

/// The tracker stage's state: per camera a detector and its region
/// tracking, the stream's stamp order and sequence, and its counters.
pub struct Tracker {
    cameras: [Camera; 2],
    order: StampOrder,
    rejections: Rejections,
    last_seq: Option<u64>,
    frames_missed: u64,
}

impl Tracker {
    /// A tracker; with `mirrored`, it also finds mirror-reversed markers.
    /// Images are searched whole every [`FULL_SCAN_EVERY`] frames and by
    /// windows around the last markers in between.
    pub fn new(mirrored: bool) -> Result<Self> {
        Self::with_full_scan_every(mirrored, FULL_SCAN_EVERY)
    }

    /// A tracker searching images whole every `n` frames (1: always).
    pub fn with_full_scan_every(mirrored: bool, n: u32) -> Result<Self> {
        let camera = |phase| -> Result<Camera> {
            Ok(Camera {
                detector: Detector::new(mirrored)?,
                regions: RegionTracker::new(n, phase),
            })
        };
        Ok(Self {
            // The second camera's full scans half a period after the first's.
            cameras: [camera(0)?, camera(n / 2)?],
            order: StampOrder::default(),
            rejections: Rejections::default(),
            last_seq: None,
            frames_missed: 0,
        })
    }

    /// Tracks one stereo frame: checks the header against the payload and
    /// the stamp order, counts frames missed before it, and finds the
    /// markers of both images, read in place through `Mat` headers. A
    /// malformed or out-of-order frame is [`Tracked::Rejected`], not an
    /// error; errors are OpenCV's ([`TrackError::OpenCv`],
    /// [`TrackError::Detection`]) and a panicked right-camera thread
    /// ([`TrackError::Panicked`]).
    pub fn step(&mut self, header: &FrameHeader, payload: &[u8]) -> Result<Tracked> {
        let _span = tracing::trace_span!("tracker_step", seq = header.seq).entered();
        if let Err(why) = header
            .validate(payload.len())
            .map_err(|e| e.to_string())
            .and_then(|()| self.order.check(header.stamp_ns).map_err(|e| e.to_string()))
        {
            self.rejections.reject("frame", header.seq, &why);
            return Ok(Tracked::Rejected(why));
        }
        // Frames overwritten in shared memory before we took them.
        if let Some(last) = self.last_seq
            && header.seq > last + 1
        {
            self.frames_missed += header.seq - last - 1;
        }
        self.last_seq = Some(header.seq);
        let mut out = StereoDetections {
            seq: header.seq,
            stamp_ns: header.stamp_ns,
            frame_published_ns: header.published_ns,
            ..Default::default()
        };
        // The two images on two threads: the right one's on a scoped thread,
        // the left one's here.
        let mut images = payload.chunks_exact(header.image_len());
        let (Some(left), Some(right)) = (images.next(), images.next()) else {
            return Err(TrackError::BadFrame {
                seq: header.seq,
                reason: "payload holds fewer than two images".into(),
            });
        };
        let [first, second] = &mut self.cameras;
        let (l, r) = std::thread::scope(|s| {
            let r = s.spawn(|| second.track(header, right));
            (first.track(header, left), r.join())
        });
        out.cameras[0] = l?;
        out.cameras[1] = r.map_err(|_| TrackError::Panicked { task: "detection" })??;
        Ok(Tracked::Detections(out))
    }

    /// Makes the full scans due on the frame [`Tracker::step`] last
    /// tracked (the same header and payload): periodic ones, and those
    /// after a marker was not seen anywhere. The stage calls it once that
    /// frame's detections are published, so that a full scan delays no
    /// detections. What it finds is searched for from the next frame on.
    /// Without it, the full scans are made in `step`, a period late.
    pub fn catch_up(&mut self, header: &FrameHeader, payload: &[u8]) -> Result<()> {
        if self.last_seq != Some(header.seq) || header.validate(payload.len()).is_err() {
            return Ok(());
        }
        let mut images = payload.chunks_exact(header.image_len());
        let (Some(left), Some(right)) = (images.next(), images.next()) else {
            return Ok(());
        };
        let [first, second] = &mut self.cameras;
        // Both due (both lost a marker): the two scans on two threads.
        if first.regions.due() && second.regions.due() {
            let r = std::thread::scope(|s| {
                let r = s.spawn(|| second.catch_up(header, right));
                first.catch_up(header, left)?;
                r.join()
                    .map_err(|_| TrackError::Panicked { task: "full scan" })?
            });
            return r;
        }
        first.catch_up(header, left)?;
        second.catch_up(header, right)
    }

    /// Frames dropped as malformed or out of order.
    pub fn rejected(&self) -> u64 {
        self.rejections.count()
    }

    /// Images searched whole, and by windows around the last markers.
    pub fn scans(&self) -> (u64, u64) {
        let (a, b) = (
            self.cameras[0].regions.scans(),
            self.cameras[1].regions.scans(),
        );
        (a.0 + b.0, a.1 + b.1)
    }

    /// Frames never received (gaps in the sequence).
    pub fn frames_missed(&self) -> u64 {
        self.frames_missed
    }
}
