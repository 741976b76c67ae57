//! ArUco detection that also finds markers seen mirror-reversed.
//!
//! A reflected marker does not decode with the stock dictionary (most
//! `DICT_4X4_50` codes are not found at all when flipped). OpenCV finds the
//! candidate quadrilaterals; we read each against the 50 codes and their
//! mirror images ([`decode`]), so one pass per image finds both kinds and
//! says which, and place the corners on lines fitted to the marker's outer
//! edges ([`refine`]). A read marker must look like its code's grid of
//! uniform cells ([`pattern`]), not a pictogram that lands on a code. Four
//! codes are their own mirror images turned
//! ([`Detector::mirror_symmetric_ids`]): found either way, reported as
//! printed. The centre is the intersection of the diagonals. Each choice is
//! measured on real photographs by the `real_set` example ([`real_set`]).
//!
//! ```no_run
//! let mut detector = tracker_proc::Detector::new(true)?;
//! let image = opencv::imgcodecs::imread("frame_left.png", opencv::imgcodecs::IMREAD_GRAYSCALE)?;
//! for m in detector.detect(&image)? {
//!     println!("id {} mirrored {} at {:?}", m.id, m.mirrored, m.center);
//! }
//! # Ok::<(), tracker_proc::TrackError>(())
//! ```

pub mod candidates;
pub mod contours;
pub mod decode;
mod error;
pub mod pattern;
pub mod real_set;
pub mod refine;
pub mod regions;
pub mod step;
pub mod threshold;

pub use decode::{
    Checks, CodeBook, Correction, Decoded, Reading, Refusal, quad_center, shortest_side,
};
pub use error::{Result, TrackError};
pub use step::{FULL_SCAN_EVERY, Tracked, Tracker};

use messages::Marker;
use opencv::aruco;
use opencv::core::{self, Mat, Point2f, Ptr, Vector};
use opencv::imgproc;
use opencv::prelude::*;

/// How the detector finds candidates, reads codes and places corners; each
/// field is one lever measured on the real-image set (see the
/// `real_set` example).
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Also find mirror-reversed markers.
    pub mirrored: bool,
    /// How many bits each code may correct.
    pub correction: Correction,
    /// Keep candidates that lie close to one another (a marker printed on a
    /// white square, markers on a sheet of labels). OpenCV 4.6 keeps only the
    /// larger of two close candidates: the white square's outline, which
    /// reads as no code, instead of the marker inside it.
    pub keep_close_candidates: bool,
    /// Read a refused candidate again on corners fitted to its edges.
    pub reread_refined: bool,
    /// Read a near miss that its fitted corners do not save as OpenCV reads
    /// ([`CodeBook::read_as_opencv`]).
    pub opencv_reading: bool,
    /// How the corners are placed.
    pub refine: Refine,
    /// What a candidate must look like to be read as a marker.
    pub checks: Checks,
    /// The adaptive threshold's window sizes, pixels: OpenCV thresholds the
    /// image once per size and finds candidates in each.
    pub threshold_windows: ThresholdWindows,
    /// Find the candidates with [`candidates::CandidateSearch`] (the same
    /// quadrilaterals as OpenCV's pass, in about half the time) rather than
    /// with OpenCV's `detectMarkers` pass. It keeps close candidates: with
    /// `keep_close_candidates` off, OpenCV's pass is used.
    pub own_search: bool,
}

/// Window sizes of the adaptive threshold: `min`, `min + step`, ... up to
/// `max` (odd, pixels), as OpenCV's `adaptiveThreshWinSize*` parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ThresholdWindows {
    /// The smallest window.
    pub min: i32,
    /// The largest window.
    pub max: i32,
    /// The step between sizes.
    pub step: i32,
}

impl ThresholdWindows {
    /// OpenCV's defaults: 3, 13 and 23 px.
    pub const STOCK: Self = Self {
        min: 3,
        max: 23,
        step: 10,
    };

    /// One size only.
    pub const fn single(size: i32) -> Self {
        Self {
            min: size,
            max: size,
            step: 10,
        }
    }
}

/// Corner placement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refine {
    /// The candidate's polygon corners (whole pixels), as OpenCV's default.
    None,
    /// OpenCV's `cornerSubPix` with its default 5 px half-window.
    Subpix,
    /// Lines fitted to the four outer edges ([`refine::refine_corners`])
    /// for markers up to 100 px a side; for larger ones `cornerSubPix`
    /// started from the lines' corners.
    Lines,
}

impl Options {
    /// Our defaults; with `mirrored`, mirror-reversed markers too.
    pub fn new(mirrored: bool) -> Self {
        Self {
            mirrored,
            correction: Correction::None,
            keep_close_candidates: true,
            reread_refined: true,
            opencv_reading: true,
            refine: Refine::Lines,
            checks: Checks::default(),
            threshold_windows: ThresholdWindows::STOCK,
            own_search: true,
        }
    }
}

/// An ArUco detector over `DICT_4X4_50`, optionally with mirror images.
///
/// OpenCV finds the candidate quadrilaterals; the codes are read here
/// ([`decode`]) so that each code corrects as many bits as its distance to
/// the others (mirror images included) allows, and a candidate that is no
/// clean two-tone code is refused; the corners come from the outer edges
/// ([`refine`]).
pub struct Detector {
    options: Options,
    dictionary: Ptr<aruco::Dictionary>,
    params: Ptr<aruco::DetectorParameters>,
    book: CodeBook,
    grey: Mat,
    search: candidates::CandidateSearch,
}

impl Detector {
    /// A detector with our defaults; with `mirrored`, it also finds
    /// mirror-reversed markers.
    pub fn new(mirrored: bool) -> Result<Self> {
        Self::with_options(Options::new(mirrored))
    }

    /// A detector with the given levers.
    pub fn with_options(options: Options) -> Result<Self> {
        let dictionary =
            aruco::get_predefined_dictionary(aruco::PREDEFINED_DICTIONARY_NAME::DICT_4X4_50)?;
        let mut params = aruco::DetectorParameters::create()?;
        params.set_corner_refinement_method(aruco::CornerRefineMethod::CORNER_REFINE_NONE as i32);
        if options.keep_close_candidates {
            params.set_min_marker_distance_rate(0.0);
        }
        let mut detector = Self {
            book: CodeBook::new(options.mirrored, options.correction)?,
            options,
            dictionary,
            params,
            grey: Mat::default(),
            search: candidates::CandidateSearch::new(),
        };
        detector.set_threshold_windows(options.threshold_windows);
        Ok(detector)
    }

    /// Ids whose mirror image is the code turned (8, 9, 17, 47): found when
    /// mirrored, but reported as printed, since the image cannot tell.
    pub fn mirror_symmetric_ids(&self) -> &[u32] {
        self.book.mirror_symmetric_ids()
    }

    /// Finds the markers of a mono8 (or BGR8) image (a `Mat`, or a view into one).
    pub fn detect<M: MatTraitConst + core::ToInputArray>(
        &mut self,
        image: &M,
    ) -> Result<Vec<Marker>> {
        if image.channels() == 3 {
            let mut grey = std::mem::take(&mut self.grey);
            imgproc::cvt_color_def(image, &mut grey, imgproc::COLOR_BGR2GRAY)?;
            let found = self.detect_grey(&grey);
            self.grey = grey;
            found
        } else {
            self.detect_grey(image)
        }
    }

    /// Finds the markers at least `min_side` pixels a side (perimeter at
    /// least four times that) of an image or a window into one: smaller
    /// outlines are not even read. [`Detector::detect`] takes OpenCV's
    /// default instead, a perimeter of 3% of the image's larger dimension,
    /// which in a small window lets through specks by the hundred.
    pub fn detect_at_least<M: MatTraitConst + core::ToInputArray>(
        &mut self,
        image: &M,
        min_side: f64,
    ) -> Result<Vec<Marker>> {
        let larger = f64::from(image.cols().max(image.rows()).max(1));
        self.params
            .set_min_marker_perimeter_rate(4.0 * min_side / larger);
        let found = self.detect(image);
        self.params
            .set_min_marker_perimeter_rate(STOCK_MIN_PERIMETER_RATE);
        found
    }

    /// [`Detector::detect_at_least`] with one adaptive-threshold window of
    /// `size` pixels in place of the detector's scales: for a window around
    /// markers of a known size, the scale that suits them.
    pub fn detect_at_least_at_scale<M: MatTraitConst + core::ToInputArray>(
        &mut self,
        image: &M,
        min_side: f64,
        size: i32,
    ) -> Result<Vec<Marker>> {
        let scale = ThresholdWindows::single(size);
        self.set_threshold_windows(scale);
        let found = self.detect_at_least(image, min_side);
        self.set_threshold_windows(self.options.threshold_windows);
        found
    }

    fn set_threshold_windows(&mut self, windows: ThresholdWindows) {
        self.params.set_adaptive_thresh_win_size_min(windows.min);
        self.params.set_adaptive_thresh_win_size_max(windows.max);
        self.params.set_adaptive_thresh_win_size_step(windows.step);
    }

    /// Every candidate quadrilateral of a grey image (OpenCV's accepted ones
    /// as well as the ones its stock reading refused), in OpenCV's corner
    /// order, with what reading it gave: for finding out why a marker is
    /// missed.
    pub fn candidates<M: MatTraitConst + core::ToInputArray>(
        &mut self,
        grey: &M,
    ) -> Result<Vec<([Point2f; 4], Reading)>> {
        let mut out = Vec::new();
        for quad in self.quads(grey)? {
            out.push(self.read(grey, quad)?);
        }
        Ok(out)
    }

    /// Whether a refused candidate deserves a second look
    /// ([`Detector::reread`]): a near miss, not a patch without contrast or
    /// a blob.
    fn worth_rereading(&self, refusal: &Refusal) -> bool {
        (self.options.reread_refined || self.options.opencv_reading)
            && matches!(
                refusal,
                Refusal::Border(..4)
                    | Refusal::Margin(_)
                    | Refusal::NoCode(..4)
                    | Refusal::Ambiguous(_)
            )
    }

    /// Reads one candidate; a near miss is read again on fitted corners
    /// ([`Detector::reread`]).
    fn read<M: MatTraitConst + core::ToInputArray>(
        &self,
        grey: &M,
        quad: [Point2f; 4],
    ) -> Result<([Point2f; 4], Reading)> {
        let first = self.book.read(grey, &quad, &self.options.checks)?;
        if let Err(refusal) = &first
            && self.worth_rereading(refusal)
            && let Some((fitted, d)) = self.reread(grey, &quad)?
        {
            return Ok((fitted, Ok(d)));
        }
        Ok((quad, first))
    }

    /// Reads a candidate again on corners fitted to its edges (whole-pixel
    /// polygon corners put the cells of a small or steeply seen marker off
    /// by a fraction of a cell); failing that, a small one as OpenCV reads
    /// ([`OPENCV_READING_UP_TO_PX`]).
    fn reread<M: MatTraitConst + core::ToInputArray>(
        &self,
        grey: &M,
        quad: &[Point2f; 4],
    ) -> Result<Option<([Point2f; 4], Decoded)>> {
        if self.options.reread_refined
            && let Some(fitted) = refine::refine_corners(grey, quad)
            && let Ok(d) = self.book.read(grey, &fitted, &self.options.checks)?
        {
            return Ok(Some((fitted, d)));
        }
        if self.options.opencv_reading
            && f64::from(shortest_side(quad)) <= OPENCV_READING_UP_TO_PX
            && let Ok(d) = self.book.read_as_opencv(grey, quad, &self.options.checks)?
        {
            return Ok(Some((*quad, d)));
        }
        Ok(None)
    }

    fn quads<M: MatTraitConst + core::ToInputArray>(
        &mut self,
        grey: &M,
    ) -> Result<Vec<[Point2f; 4]>> {
        if self.options.own_search && self.options.keep_close_candidates {
            let windows = ThresholdWindows {
                min: self.params.adaptive_thresh_win_size_min(),
                max: self.params.adaptive_thresh_win_size_max(),
                step: self.params.adaptive_thresh_win_size_step(),
            };
            return self.search.quads(grey, windows, &self.params);
        }
        let (corners, _, rejected) = opencv_pass(grey, &self.dictionary, &self.params)?;
        Ok(corners
            .iter()
            .chain(rejected.iter())
            .filter_map(|q| q.to_vec().try_into().ok())
            .collect())
    }

    fn detect_grey<M: MatTraitConst + core::ToInputArray>(
        &mut self,
        grey: &M,
    ) -> Result<Vec<Marker>> {
        // Every candidate, read by us: OpenCV's accepted ones as well as the
        // ones its stock reading refused.
        let mut found: Vec<([Point2f; 4], Decoded)> = Vec::new();
        let mut near_misses = Vec::new();
        for quad in self.quads(grey)? {
            match self.book.read(grey, &quad, &self.options.checks)? {
                Ok(d) => found.push((quad, d)),
                Err(refusal) if self.worth_rereading(&refusal) => near_misses.push(quad),
                Err(_) => {}
            }
        }
        // A near miss gets a second look unless it is another outline of a
        // marker already read (the contours of one printed marker come in pairs).
        for quad in near_misses {
            if found.iter().any(|(q, _)| overlapping(q, &quad)) {
                continue;
            }
            if let Some(read) = self.reread(grey, &quad)? {
                found.push(read);
            }
        }
        let found: Vec<([Point2f; 4], Decoded)> = best_of_overlapping(found)
            .into_iter()
            .map(|(quad, d)| {
                let k = d.rotation;
                let ordered = [
                    quad[k],
                    quad[(k + 1) % 4],
                    quad[(k + 2) % 4],
                    quad[(k + 3) % 4],
                ];
                (ordered, d)
            })
            .collect();
        let mut out = Vec::with_capacity(found.len());
        for (quad, d) in found {
            let quad = match self.options.refine {
                Refine::None => quad,
                Refine::Lines if shortest_side(&quad) <= LINES_UP_TO_PX => {
                    refine::refine_corners(grey, &quad).unwrap_or(quad)
                }
                Refine::Lines => {
                    let start = refine::refine_corners(grey, &quad).unwrap_or(quad);
                    subpix(grey, &start)?
                }
                Refine::Subpix => subpix(grey, &quad)?,
            };
            // A pictogram that lands on a code fills its cells unevenly; a
            // marker on paper that is not flat only seems to, until the
            // grid follows its bowed edges.
            if let Some(code) = self.book.code(d.id, d.mirrored) {
                let max = self.options.checks.max_misfit;
                let fits = pattern::misfit(grey, &quad, &code)? <= max
                    || refine::edge_bows(grey, &quad).is_some_and(|bows| {
                        pattern::misfit_bent(grey, &quad, &bows, &code).is_ok_and(|m| m <= max)
                    });
                if !fits {
                    continue;
                }
            }
            let c: Vec<[f64; 2]> = quad
                .iter()
                .map(|p| [f64::from(p.x), f64::from(p.y)])
                .collect();
            let Some(center) = diagonal_intersection(&c) else {
                continue;
            };
            let mut flat = [0.0; 8];
            for (k, p) in c.iter().enumerate() {
                flat[2 * k] = p[0];
                flat[2 * k + 1] = p[1];
            }
            out.push(Marker {
                id: d.id,
                mirrored: u32::from(d.mirrored),
                corners: flat,
                center,
            });
        }
        Ok(out)
    }
}

/// Quads of one OpenCV `detectMarkers` pass: the markers it read (corners,
/// ids) and the candidates it refused.
type OpenCvPass = (
    Vector<Vector<Point2f>>,
    Vector<i32>,
    Vector<Vector<Point2f>>,
);

fn opencv_pass(
    image: &impl core::ToInputArray,
    dictionary: &Ptr<aruco::Dictionary>,
    params: &Ptr<aruco::DetectorParameters>,
) -> Result<OpenCvPass> {
    let mut corners = Vector::<Vector<Point2f>>::new();
    let mut ids = Vector::<i32>::new();
    let mut rejected = Vector::<Vector<Point2f>>::new();
    aruco::detect_markers(
        image,
        dictionary,
        &mut corners,
        &mut ids,
        params,
        &mut rejected,
    )
    .map_err(TrackError::Detection)?;
    Ok((corners, ids, rejected))
}

/// OpenCV's default smallest candidate perimeter, as a fraction of the
/// image's larger dimension.
const STOCK_MIN_PERIMETER_RATE: f64 = 0.03;

/// Markers up to this side (pixels) get corners from edge lines; larger
/// ones from `cornerSubPix` (whose 5 px window then stays well inside the
/// white margin and the border) started from the edge lines' corners. On
/// rendered frames edge lines alone put the corners of sharp 130-200 px
/// markers off by up to 0.9 px (the lens bends long edges), and
/// `cornerSubPix` alone, started from the candidate's polygon, put blurred
/// ones off by 4-10 px (the polygon cuts a blurred corner by up to 9 px,
/// beyond its window's reach).
const LINES_UP_TO_PX: f32 = 100.0;

/// Longest shortest side, pixels, of a near miss read again as OpenCV reads
/// ([`CodeBook::read_as_opencv`]): under about 2.7 px a cell, a lens's blur
/// spans a whole cell and washes its average towards the threshold, while
/// on larger cells a cell at the threshold means the pattern is not two-tone
/// (on the real-image set, the one extra read above this size was a ChArUco
/// board's 6x6 marker).
const OPENCV_READING_UP_TO_PX: f64 = 16.0;

/// OpenCV's stock pass, the baseline the benchmarks and the real-image set
/// compare against: `detectMarkers` with `DICT_4X4_50` and default
/// parameters (no corner refinement); printed markers only.
pub struct StockPass {
    dictionary: Ptr<aruco::Dictionary>,
    params: Ptr<aruco::DetectorParameters>,
}

impl StockPass {
    /// The stock dictionary and parameters.
    pub fn new() -> Result<Self> {
        Ok(Self {
            dictionary: aruco::get_predefined_dictionary(
                aruco::PREDEFINED_DICTIONARY_NAME::DICT_4X4_50,
            )?,
            params: aruco::DetectorParameters::create()?,
        })
    }

    /// Ids and corners of the markers found.
    pub fn detect(&self, image: &impl core::ToInputArray) -> Result<Vec<(u32, [Point2f; 4])>> {
        let (corners, ids, _) = opencv_pass(image, &self.dictionary, &self.params)?;
        Ok(ids
            .iter()
            .zip(corners.iter())
            .filter_map(|(id, q)| Some((u32::try_from(id).ok()?, q.to_vec().try_into().ok()?)))
            .collect())
    }
}

/// One report per marker: of read candidates whose centres lie within half a
/// side of each other (the contours of one printed marker), the one read
/// with fewest corrected bits and the clearest cells.
fn best_of_overlapping(mut found: Vec<([Point2f; 4], Decoded)>) -> Vec<([Point2f; 4], Decoded)> {
    found.sort_by(|a, b| {
        a.1.errors
            .cmp(&b.1.errors)
            .then(b.1.margin.total_cmp(&a.1.margin))
    });
    let mut kept: Vec<([Point2f; 4], Decoded)> = Vec::new();
    for (q, d) in found {
        if !kept.iter().any(|(kq, _)| overlapping(kq, &q)) {
            kept.push((q, d));
        }
    }
    kept
}

/// Whether two quadrilaterals are outlines of one marker: centres closer
/// than half the longer of their shortest sides.
fn overlapping(a: &[Point2f; 4], b: &[Point2f; 4]) -> bool {
    let ((ax, ay), (bx, by)) = (quad_center(a), quad_center(b));
    (ax - bx).hypot(ay - by) < 0.5 * shortest_side(a).max(shortest_side(b))
}

/// OpenCV's corner refinement with its default window.
fn subpix(grey: &impl core::ToInputArray, quad: &[Point2f; 4]) -> Result<[Point2f; 4]> {
    let mut points = Vector::<Point2f>::from_iter(quad.iter().copied());
    imgproc::corner_sub_pix(
        grey,
        &mut points,
        core::Size::new(5, 5),
        core::Size::new(-1, -1),
        core::TermCriteria::new(core::TermCriteria_COUNT + core::TermCriteria_EPS, 30, 0.1)?,
    )?;
    Ok([
        points.get(0)?,
        points.get(1)?,
        points.get(2)?,
        points.get(3)?,
    ])
}

/// Where the diagonals 0-2 and 1-3 of a quadrilateral cross.
pub fn diagonal_intersection(c: &[[f64; 2]]) -> Option<[f64; 2]> {
    let (p, r) = (c[0], [c[2][0] - c[0][0], c[2][1] - c[0][1]]);
    let (q, s) = (c[1], [c[3][0] - c[1][0], c[3][1] - c[1][1]]);
    let denom = r[0] * s[1] - r[1] * s[0];
    if denom.abs() < 1e-12 {
        return None;
    }
    let t = ((q[0] - p[0]) * s[1] - (q[1] - p[1]) * s[0]) / denom;
    Some([p[0] + t * r[0], p[1] + t * r[1]])
}
