//! Tracking markers by region: between full scans of an image, only the
//! regions around the markers of the last frame are searched.
//!
//! A marker moves little between frames, so most of an image's pixels need
//! no search. Each camera keeps what it found last; the next frame is
//! searched in a window around each of those markers (grown by half the
//! marker's side and a motion allowance, overlapping windows merged) with the same
//! [`Detector`], on the same pixels, so what it finds there it finds as a
//! full scan would; a marker cut by its window's edge is searched for again
//! in a larger window. A search of the whole image at a quarter of its
//! resolution looks out for markers outside the windows, and those it
//! sees there are searched for in windows of their own. While a marker
//! seen within the last `full_scan_every` frames is missing (it may come
//! back anywhere, as the arm's card does after a fast move), or none is
//! known, or one was not found again in its window, that look-out is at
//! half resolution instead of a quarter.
//!
//! No frame waits for a search of the whole image at full resolution but
//! the first: it is made by [`RegionTracker::catch_up`] once the frame's
//! detections are out, every `full_scan_every` frames and after a frame
//! where a marker of the last one was not found anywhere (gone, or too
//! small or blurred for the look-out); what it finds is searched for from
//! the next frame on. A marker too small for the look-out (under about
//! 24 px a side, 12 px when wary) that enters the view is found at the next
//! full scan at the latest. The two cameras' full scans are staggered so
//! that no frame pays for both.

use messages::Marker;
use opencv::core::{Mat, Rect, Size};
use opencv::imgproc;
use opencv::prelude::*;

use crate::{Detector, Result};

/// How far a marker may move between two frames and still be found in its
/// window, pixels (besides half its side).
const MOTION_ALLOWANCE_PX: f64 = 24.0;

/// The whole image is looked over for markers outside the windows at
/// 1/`PROBE_SCALE` of its resolution: markers of about 24 px a side and up.
const PROBE_SCALE: i32 = 4;

/// ... and at 1/`WARY_PROBE_SCALE` while a marker seen lately is missing or
/// none is known: markers of about 12 px a side and up.
const WARY_PROBE_SCALE: i32 = 2;

/// The smallest side of a marker read in the low-resolution search, in
/// its pixels: the reading's own least ([`crate::Checks::min_side`]).
const PROBE_MIN_SIDE_PX: f64 = 6.0;

/// Per camera, what was found last, what was seen lately (id, mirrored,
/// frames ago) and when the last full scan was.
#[derive(Debug, Clone, Default)]
struct CameraState {
    last: Vec<Marker>,
    lately: Vec<(u32, u32, u32)>,
    since_full: u32,
    /// Whether an image was searched whole yet (the first one is).
    started: bool,
}

impl CameraState {
    /// Remembers `found` as seen now; forgets what was not seen for `every` frames.
    fn saw(&mut self, found: &[Marker], every: u32) {
        for entry in &mut self.lately {
            entry.2 += 1;
        }
        self.lately.retain(|e| e.2 < every);
        self.saw_again(found);
    }

    /// Replaces what the last frame showed by `found`, a (second) look at it.
    fn saw_again(&mut self, found: &[Marker]) {
        for m in found {
            match self
                .lately
                .iter_mut()
                .find(|e| e.0 == m.id && e.1 == m.mirrored)
            {
                Some(e) => e.2 = 0,
                None => self.lately.push((m.id, m.mirrored, 0)),
            }
        }
        self.last = found.to_vec();
    }

    /// Whether a marker seen lately is missing from the last frame (it may
    /// be back anywhere: only a full scan finds it at once).
    fn missing_one(&self) -> bool {
        self.lately
            .iter()
            .any(|e| !self.last.iter().any(|m| m.id == e.0 && m.mirrored == e.1))
    }
}

/// What one image's search did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Search {
    /// The whole image.
    Full,
    /// Only the windows around the last markers.
    Windows,
}

/// Region tracking for one camera's stream.
pub struct RegionTracker {
    every: u32,
    phase: u32,
    state: CameraState,
    full_scans: u64,
    window_scans: u64,
    small: Mat,
    /// A periodic full scan is due, for [`RegionTracker::catch_up`].
    due: bool,
}

impl RegionTracker {
    /// Full scans every `full_scan_every` frames (1: every frame, no
    /// tracking): of the first image, then after `full_scan_every - phase`
    /// frames, then periodically (a stereo pair's second camera goes half a
    /// period ahead, so that the two cameras' full scans fall on different
    /// frames).
    pub fn new(full_scan_every: u32, phase: u32) -> Self {
        let every = full_scan_every.max(1);
        Self {
            every,
            phase: phase % every,
            state: CameraState::default(),
            full_scans: 0,
            window_scans: 0,
            small: Mat::default(),
            due: false,
        }
    }

    /// Images searched whole, and by windows, so far.
    pub fn scans(&self) -> (u64, u64) {
        (self.full_scans, self.window_scans)
    }

    /// Finds the markers of the next image (a `Mat` or a view into one).
    pub fn detect(
        &mut self,
        detector: &mut Detector,
        image: &(impl MatTraitConst + opencv::core::ToInputArray),
    ) -> Result<(Vec<Marker>, Search)> {
        let state = &mut self.state;
        state.since_full += 1;
        // With a marker missing, or none known, the look-out is sharper: a
        // marker back from a fast move, blurred or small, must be seen.
        let wary = state.last.is_empty() || state.missing_one();
        // The periodic full scan waits for `catch_up`, after the frame's
        // detections are out; if nobody catches up, it is made here.
        self.due = state.since_full >= self.every;
        // Every image whole (`full_scan_every` 1) means each frame's own
        // detections come from a full scan.
        if state.started && self.every > 1 && state.since_full < 2 * self.every {
            let mut found = search_windows(detector, image, &state.last)?;
            // A marker not found again in its window has moved further than
            // allowed, or gone: the look-out is sharper at once.
            let lost = !state
                .last
                .iter()
                .all(|old| found.iter().any(|m| same(m, old)));
            let probe_scale = if wary || lost {
                WARY_PROBE_SCALE
            } else {
                PROBE_SCALE
            };
            // Markers the low-resolution search sees outside the windows are
            // searched for at full resolution in windows of their own.
            let outside = seen_outside(detector, image, &found, probe_scale, &mut self.small)?;
            for m in search_windows(detector, image, &outside)? {
                if !found.iter().any(|f| same(f, &m)) {
                    found.push(m);
                }
            }
            // Still missing anywhere: gone, or too small or blurred for the
            // look-out. The whole image is searched once the detections are out.
            let missing = state.last.iter().any(|old| {
                !found
                    .iter()
                    .any(|m| m.id == old.id && m.mirrored == old.mirrored)
            });
            if missing {
                self.due = true;
            }
            state.saw(&found, self.every);
            self.window_scans += 1;
            return Ok((found, Search::Windows));
        }
        let found = detector.detect(image)?;
        state.saw(&found, self.every);
        state.since_full = if state.started { 0 } else { self.phase };
        state.started = true;
        self.due = false;
        self.full_scans += 1;
        Ok((found, Search::Full))
    }

    /// Whether [`RegionTracker::catch_up`] has a full scan to make.
    pub fn due(&self) -> bool {
        self.due
    }

    /// Makes the periodic full scan of the image [`RegionTracker::detect`]
    /// last searched by windows, once its detections are out: what it finds
    /// (a marker too small for the low-resolution search, come into view)
    /// is searched for from the next frame on. Returns whether it scanned.
    pub fn catch_up(
        &mut self,
        detector: &mut Detector,
        image: &(impl MatTraitConst + opencv::core::ToInputArray),
    ) -> Result<bool> {
        if !self.due {
            return Ok(false);
        }
        let found = detector.detect(image)?;
        self.state.saw_again(&found);
        self.state.since_full = 0;
        self.due = false;
        self.full_scans += 1;
        Ok(true)
    }
}

/// The markers a search of the whole image at 1/`scale` of its resolution
/// sees that are not among `found`, in full-resolution pixels.
fn seen_outside(
    detector: &mut Detector,
    image: &(impl MatTraitConst + opencv::core::ToInputArray),
    found: &[Marker],
    scale: i32,
    small: &mut Mat,
) -> Result<Vec<Marker>> {
    let size = Size::new(image.cols() / scale, image.rows() / scale);
    imgproc::resize(image, small, size, 0.0, 0.0, imgproc::INTER_AREA)?;
    let s = f64::from(scale);
    // Markers under PROBE_MIN_SIDE_PX (at this scale) the reading refuses
    // anyway: not even looked at.
    Ok(detector
        .detect_at_least(small, PROBE_MIN_SIDE_PX)?
        .into_iter()
        .map(|mut m| {
            for v in m.corners.iter_mut().chain(m.center.iter_mut()) {
                *v = s * (*v + 0.5) - 0.5;
            }
            m
        })
        .filter(|m| !found.iter().any(|f| same(f, m)))
        .collect())
}

/// Whether `m` is `old` (same id and flag) where it could have moved in a frame.
fn same(m: &Marker, old: &Marker) -> bool {
    m.id == old.id && m.mirrored == old.mirrored && near(m, old)
}

/// Searches the windows around `last` at full resolution; returns what
/// they hold. A marker cut by its window's edge is searched for again in a
/// window grown around it; if that cuts it too, it is left out (its corners
/// would not be a full scan's).
fn search_windows(
    detector: &mut Detector,
    image: &(impl MatTraitConst + opencv::core::ToInputArray),
    last: &[Marker],
) -> Result<Vec<Marker>> {
    let (width, height) = (image.cols(), image.rows());
    let mut found = Vec::new();
    let mut cut = Vec::new();
    for window in merged_windows(last, width, height, 1.0) {
        found.extend(search_window(detector, image, &window, &mut cut)?);
    }
    let mut still_cut = Vec::new();
    for window in merged_windows(&cut, width, height, 2.0) {
        for m in search_window(detector, image, &window, &mut still_cut)? {
            if !found.iter().any(|f| same(f, &m)) {
                found.push(m);
            }
        }
    }
    Ok(found)
}

/// A part of the image searched for markers seen there last.
struct Window {
    rect: Rect,
    /// The smallest side searched for: half the smallest of its markers'
    /// (none shrinks by half in a frame).
    min_side: f64,
    /// How many markers it was made for.
    markers: usize,
}

/// The windows around `markers` (see [`window_around`], with the growth
/// times `grow`), overlapping ones merged.
fn merged_windows(markers: &[Marker], width: i32, height: i32, grow: f64) -> Vec<Window> {
    let mut windows: Vec<Window> = Vec::new();
    for m in markers {
        let mut window = Window {
            rect: window_around(m, width, height, grow),
            min_side: 0.5 * shortest(m),
            markers: 1,
        };
        while let Some(j) = windows
            .iter()
            .position(|w| (w.rect & window.rect).area() > 0)
        {
            let other = windows.swap_remove(j);
            window.rect |= other.rect;
            window.min_side = window.min_side.min(other.min_side);
            window.markers += other.markers;
        }
        windows.push(window);
    }
    windows
}

impl Window {
    /// The one adaptive-threshold scale for its markers: about one and a
    /// half cells of the smallest it looks for, odd, within OpenCV's
    /// default scales (3 to 23 px).
    fn threshold_scale(&self) -> i32 {
        let cell = 2.0 * self.min_side / 6.0;
        ((1.5 * cell).round() as i32 | 1).clamp(3, 23)
    }
}

/// The markers of one window, in image pixels; those its edge cuts go to
/// `cut` instead.
fn search_window(
    detector: &mut Detector,
    image: &(impl MatTraitConst + opencv::core::ToInputArray),
    window: &Window,
    cut: &mut Vec<Marker>,
) -> Result<Vec<Marker>> {
    let (width, height) = (image.cols(), image.rows());
    let view = Mat::roi(image, window.rect)?;
    // One threshold scale suited to the markers' size first; all of the
    // detector's scales when that does not find as many as were there.
    let mut markers =
        detector.detect_at_least_at_scale(&view, window.min_side, window.threshold_scale())?;
    if markers.len() < window.markers {
        markers = detector.detect_at_least(&view, window.min_side)?;
    }
    let mut found = Vec::new();
    for mut m in markers {
        let clear = clear_of_edges(&m, window.rect, width, height);
        let (dx, dy) = (f64::from(window.rect.x), f64::from(window.rect.y));
        for k in 0..4 {
            m.corners[2 * k] += dx;
            m.corners[2 * k + 1] += dy;
        }
        m.center[0] += dx;
        m.center[1] += dy;
        if clear { found.push(m) } else { cut.push(m) }
    }
    Ok(found)
}

/// Pixels a marker found in a window must keep from the window's edges
/// (those inside the image): what the detector looks at around a marker.
const EDGE_CLEARANCE_PX: f64 = 8.0;

/// Whether `m` (in window coordinates) keeps clear of the window's edges
/// that are not the image's.
fn clear_of_edges(m: &Marker, window: Rect, width: i32, height: i32) -> bool {
    let xs = [m.corners[0], m.corners[2], m.corners[4], m.corners[6]];
    let ys = [m.corners[1], m.corners[3], m.corners[5], m.corners[7]];
    let (w, h) = (f64::from(window.width), f64::from(window.height));
    let c = EDGE_CLEARANCE_PX;
    (window.x == 0 || xs.iter().all(|&x| x >= c))
        && (window.y == 0 || ys.iter().all(|&y| y >= c))
        && (window.x + window.width == width || xs.iter().all(|&x| x <= w - c))
        && (window.y + window.height == height || ys.iter().all(|&y| y <= h - c))
}

/// The marker's side (its longest edge), pixels.
fn side(m: &Marker) -> f64 {
    edges(m).fold(0.0, f64::max)
}

/// The marker's shortest edge, pixels.
fn shortest(m: &Marker) -> f64 {
    edges(m).fold(f64::INFINITY, f64::min)
}

/// The lengths of the marker's four edges, pixels.
fn edges(m: &Marker) -> impl Iterator<Item = f64> + '_ {
    (0..4).map(|i| {
        let j = (i + 1) % 4;
        (m.corners[2 * i] - m.corners[2 * j]).hypot(m.corners[2 * i + 1] - m.corners[2 * j + 1])
    })
}

/// Whether `m` is where `old` could have moved in a frame.
fn near(m: &Marker, old: &Marker) -> bool {
    let d = (m.center[0] - old.center[0]).hypot(m.center[1] - old.center[1]);
    d <= 0.5 * side(old) + MOTION_ALLOWANCE_PX
}

/// The window a marker is searched for in the next frame: its bounding box
/// grown by `grow` times half its side and the motion allowance, within the
/// image.
fn window_around(m: &Marker, width: i32, height: i32, grow: f64) -> Rect {
    let grow = grow * (0.5 * side(m) + MOTION_ALLOWANCE_PX);
    let xs = [m.corners[0], m.corners[2], m.corners[4], m.corners[6]];
    let ys = [m.corners[1], m.corners[3], m.corners[5], m.corners[7]];
    let min = |v: [f64; 4]| v.iter().copied().fold(f64::INFINITY, f64::min);
    let max = |v: [f64; 4]| v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let x0 = ((min(xs) - grow).floor() as i32).clamp(0, width - 1);
    let y0 = ((min(ys) - grow).floor() as i32).clamp(0, height - 1);
    let x1 = ((max(xs) + grow).ceil() as i32).clamp(x0 + 1, width);
    let y1 = ((max(ys) + grow).ceil() as i32).clamp(y0 + 1, height);
    Rect::new(x0, y0, x1 - x0, y1 - y0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn marker(id: u32, x: f64, y: f64, s: f64) -> Marker {
        Marker {
            id,
            mirrored: 0,
            corners: [x, y, x + s, y, x + s, y + s, x, y + s],
            center: [x + s / 2.0, y + s / 2.0],
        }
    }

    /// Runs `frames` blank images through a tracker, catching up after
    /// each or not; returns (searched whole, by windows, whole after the detections).
    fn schedule(every: u32, frames: usize, catch_up: bool) -> (u64, u64, u64) {
        let mut detector = Detector::new(true).unwrap();
        let blank = Mat::zeros(480, 640, opencv::core::CV_8UC1)
            .unwrap()
            .to_mat()
            .unwrap();
        let mut tracker = RegionTracker::new(every, 0);
        let mut caught_up = 0;
        for _ in 0..frames {
            tracker.detect(&mut detector, &blank).unwrap();
            if catch_up && tracker.catch_up(&mut detector, &blank).unwrap() {
                caught_up += 1;
            }
        }
        let (whole, windows) = tracker.scans();
        (whole, windows, caught_up)
    }

    #[test]
    fn periodic_full_scans_come_after_the_detections_or_a_period_late() {
        // Every image whole: each frame's own detections.
        assert_eq!(schedule(1, 5, true), (5, 0, 0));
        // The first image whole; then every 4th after the detections are out.
        assert_eq!(schedule(4, 9, true), (3, 8, 2));
        // Nobody catches up: made in `detect`, a period late.
        assert_eq!(schedule(4, 9, false), (2, 7, 0));
    }

    /// A 640x480 white image with DICT_4X4_50 marker `id` (60 px) at `(x, y)`.
    fn image_with_marker(id: i32, at: Option<(i32, i32)>) -> Mat {
        let mut image = Mat::new_rows_cols_with_default(
            480,
            640,
            opencv::core::CV_8UC1,
            opencv::core::Scalar::all(255.0),
        )
        .unwrap();
        if let Some((x, y)) = at {
            let dict = opencv::aruco::get_predefined_dictionary(
                opencv::aruco::PREDEFINED_DICTIONARY_NAME::DICT_4X4_50,
            )
            .unwrap();
            let mut code = Mat::default();
            opencv::aruco::draw_marker(&dict, id, 60, &mut code, 1).unwrap();
            let mut roi = Mat::roi_mut(&mut image, Rect::new(x, y, 60, 60)).unwrap();
            code.copy_to(&mut roi).unwrap();
        }
        image
    }

    #[test]
    fn a_marker_that_jumps_or_goes_costs_no_full_scan_before_its_detections() {
        let mut detector = Detector::new(true).unwrap();
        let mut tracker = RegionTracker::new(10, 0);
        let ids = |found: &[Marker]| found.iter().map(|m| m.id).collect::<Vec<_>>();
        // First image: searched whole.
        let (found, search) = tracker
            .detect(&mut detector, &image_with_marker(7, Some((40, 40))))
            .unwrap();
        assert_eq!((ids(&found), search), (vec![7], Search::Full));
        // It jumps far beyond its window: the look-out finds it in the same
        // frame, at full resolution in a window of its own.
        let jumped = image_with_marker(7, Some((500, 380)));
        let (found, search) = tracker.detect(&mut detector, &jumped).unwrap();
        assert_eq!((ids(&found), search), (vec![7], Search::Windows));
        let full = detector.detect(&jumped).unwrap();
        assert_eq!(found[0].corners, full[0].corners, "the full scan's corners");
        assert!(!tracker.due(), "nothing missing, no full scan due");
        // It goes: the frame's detections come from the windows (none), and
        // the whole image is searched after them.
        let gone = image_with_marker(7, None);
        let (found, search) = tracker.detect(&mut detector, &gone).unwrap();
        assert_eq!((found.len(), search), (0, Search::Windows));
        assert!(tracker.due());
        assert!(tracker.catch_up(&mut detector, &gone).unwrap());
        assert_eq!(tracker.scans(), (2, 2));
    }

    #[test]
    fn windows_grow_by_the_side_and_stay_in_the_image() {
        let w = window_around(&marker(0, 100.0, 50.0, 40.0), 640, 480, 1.0);
        assert_eq!(w, Rect::new(56, 6, 128, 128));
        let edge = window_around(&marker(0, 620.0, 460.0, 30.0), 640, 480, 1.0);
        assert!(edge.x + edge.width <= 640 && edge.y + edge.height <= 480);
    }

    #[test]
    fn a_marker_at_a_window_edge_inside_the_image_is_not_clear() {
        let window = Rect::new(100, 100, 120, 120);
        assert!(clear_of_edges(
            &marker(0, 20.0, 20.0, 40.0),
            window,
            640,
            480
        ));
        assert!(!clear_of_edges(
            &marker(0, 3.0, 20.0, 40.0),
            window,
            640,
            480
        ));
        assert!(!clear_of_edges(
            &marker(0, 20.0, 20.0, 96.0),
            window,
            640,
            480
        ));
        // At the image's own edge a window edge cuts nothing.
        assert!(clear_of_edges(
            &marker(0, 3.0, 20.0, 40.0),
            Rect::new(0, 100, 120, 120),
            640,
            480
        ));
    }

    #[test]
    fn a_marker_seen_lately_and_missing_now_is_missed_until_forgotten() {
        let mut state = CameraState::default();
        state.saw(
            &[marker(0, 10.0, 10.0, 40.0), marker(7, 200.0, 10.0, 40.0)],
            3,
        );
        assert!(!state.missing_one());
        state.saw(&[marker(7, 200.0, 10.0, 40.0)], 3);
        assert!(state.missing_one(), "marker 0 went missing");
        state.saw(&[marker(7, 200.0, 10.0, 40.0)], 3);
        state.saw(&[marker(7, 200.0, 10.0, 40.0)], 3);
        assert!(!state.missing_one(), "forgotten after 3 frames");
    }

    #[test]
    fn a_marker_is_near_where_it_was_within_its_side_and_the_allowance() {
        let old = marker(3, 100.0, 100.0, 40.0);
        assert!(near(&marker(3, 140.0, 100.0, 40.0), &old));
        assert!(!near(&marker(3, 150.0, 100.0, 40.0), &old));
    }
}
