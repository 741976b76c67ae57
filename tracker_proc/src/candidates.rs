//! The candidate quadrilaterals of an image, as OpenCV 4.6's `detectMarkers`
//! finds them before reading any code (`_detectCandidates` with
//! `minMarkerDistanceRate` 0): per adaptive-threshold window, the borders
//! of the thresholded image whose length suits a marker, approximated by a
//! polygon, kept if it is a convex quadrilateral whose sides are not too
//! short and which keeps off the image's edge; corners turned clockwise.
//!
//! The borders come from [`BorderScanner`] rather than OpenCV's
//! `findContours` (see [`crate::contours`] for why); the rest is OpenCV's
//! own functions with the parameters of the detector's
//! `DetectorParameters`. Nothing is read here: OpenCV's pass would also
//! try every candidate against the stock dictionary, which our reading
//! ([`crate::decode`]) does instead.

use opencv::aruco::DetectorParameters;
use opencv::core::{Point, Point2f, Ptr, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use crate::ThresholdWindows;
use crate::contours::BorderScanner;
use crate::error::Result;
use crate::threshold::MeanThreshold;

/// Finds candidate quadrilaterals; keeps its buffers between images.
#[derive(Default)]
pub struct CandidateSearch {
    borders: BorderScanner,
    threshold: MeanThreshold,
    /// The image's rows, when they are not contiguous (a window's view).
    rows: Vec<u8>,
}

/// What a border must be to become a candidate, from `DetectorParameters`.
struct Shape {
    lengths: std::ops::RangeInclusive<usize>,
    accuracy_rate: f64,
    min_corner_distance_rate: f64,
    min_distance_to_border: i32,
}

impl CandidateSearch {
    /// A search with empty buffers.
    pub fn new() -> Self {
        Self::default()
    }

    /// The candidates of `grey` at each of `windows`, with the thresholds
    /// and shape limits of `params`, in OpenCV's corner order.
    pub fn quads(
        &mut self,
        grey: &(impl MatTraitConst + opencv::core::ToInputArray),
        windows: ThresholdWindows,
        params: &Ptr<DetectorParameters>,
    ) -> Result<Vec<[Point2f; 4]>> {
        let (cols, rows) = (grey.cols(), grey.rows());
        if cols <= 0 || rows <= 0 {
            return Ok(Vec::new());
        }
        let larger = f64::from(cols.max(rows));
        // As OpenCV: the limits in whole points, truncated.
        let shape = Shape {
            lengths: (params.min_marker_perimeter_rate() * larger) as u32 as usize
                ..=(params.max_marker_perimeter_rate() * larger) as u32 as usize,
            accuracy_rate: params.polygonal_approx_accuracy_rate(),
            min_corner_distance_rate: params.min_corner_distance_rate(),
            min_distance_to_border: params.min_distance_to_border(),
        };
        let (w, h) = (cols as usize, rows as usize);
        // A window's view into a frame is not contiguous: its rows are copied.
        let pixels: &[u8] = if grey.is_continuous() {
            grey.data_bytes()?
        } else {
            self.rows.clear();
            for y in 0..rows {
                self.rows.extend_from_slice(grey.at_row::<u8>(y)?);
            }
            &self.rows
        };
        let stride = w;
        self.threshold
            .prepare(pixels, w, h, stride, windows.max.max(3) as usize);
        let sizes: Vec<usize> = (windows.min..=windows.max)
            .step_by(windows.step.max(1) as usize)
            .map(|s| s as usize)
            .collect();
        let c = params.adaptive_thresh_constant();
        let threshold = &self.threshold;
        let image = Image {
            pixels,
            width: w,
            height: h,
        };
        let mut quads = Vec::new();
        for window in sizes {
            quads.extend(window_quads(
                &mut self.borders,
                threshold,
                &image,
                window,
                c,
                &shape,
            )?);
        }
        for q in &mut quads {
            clockwise(q);
        }
        Ok(quads)
    }
}

/// A grey image's pixels, rows contiguous.
struct Image<'a> {
    pixels: &'a [u8],
    width: usize,
    height: usize,
}

/// The candidates of one threshold `window` (constant `c`), in the order
/// OpenCV lists their borders.
fn window_quads(
    borders: &mut BorderScanner,
    threshold: &MeanThreshold,
    image: &Image<'_>,
    window: usize,
    c: f64,
    shape: &Shape,
) -> opencv::Result<Vec<[Point2f; 4]>> {
    let (w, h) = (image.width, image.height);
    let (work, offset, step) = borders.frame(w, h);
    threshold.binary_inv(image.pixels, window, c, work, offset, step);
    let (mut quads, mut failed) = (Vec::new(), None);
    borders.scan_framed(w, h, shape.lengths.clone(), |points| {
        match quad_of(points, shape, w as i32, h as i32) {
            Ok(Some(q)) => quads.push(q),
            Ok(None) => {}
            Err(e) => {
                failed.get_or_insert(e);
            }
        }
    });
    failed.map_or(Ok(quads), Err)
}

/// The quadrilateral a border outlines, if it passes OpenCV's checks
/// (`_findMarkerContours`).
fn quad_of(
    points: &[Point],
    shape: &Shape,
    cols: i32,
    rows: i32,
) -> opencv::Result<Option<[Point2f; 4]>> {
    let contour = Vector::<Point>::from_slice(points);
    let mut approx = Vector::<Point>::new();
    imgproc::approx_poly_dp(
        &contour,
        &mut approx,
        points.len() as f64 * shape.accuracy_rate,
        true,
    )?;
    if approx.len() != 4 || !imgproc::is_contour_convex(&approx)? {
        return Ok(None);
    }
    let c: [Point; 4] = [
        approx.get(0)?,
        approx.get(1)?,
        approx.get(2)?,
        approx.get(3)?,
    ];
    let shortest_sq = (0..4)
        .map(|j| {
            let (a, b) = (c[j], c[(j + 1) % 4]);
            let (dx, dy) = (f64::from(a.x - b.x), f64::from(a.y - b.y));
            dx * dx + dy * dy
        })
        .fold(f64::from(cols.max(rows)).powi(2), f64::min);
    let min_corner_distance = points.len() as f64 * shape.min_corner_distance_rate;
    if shortest_sq < min_corner_distance * min_corner_distance {
        return Ok(None);
    }
    let d = shape.min_distance_to_border;
    if c.iter()
        .any(|p| p.x < d || p.y < d || p.x > cols - 1 - d || p.y > rows - 1 - d)
    {
        return Ok(None);
    }
    Ok(Some(c.map(|p| Point2f::new(p.x as f32, p.y as f32))))
}

/// Puts the corners in clockwise order (in image coordinates), as
/// `_reorderCandidatesCorners`.
fn clockwise(q: &mut [Point2f; 4]) {
    let (dx1, dy1) = (f64::from(q[1].x - q[0].x), f64::from(q[1].y - q[0].y));
    let (dx2, dy2) = (f64::from(q[2].x - q[0].x), f64::from(q[2].y - q[0].y));
    if dx1 * dy2 - dy1 * dx2 < 0.0 {
        q.swap(1, 3);
    }
}
