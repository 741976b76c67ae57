//! Scoring detectors on the real-image test set.
//!
//! `scripts/real_markers.py` turns the photographs of `tests/data/real_markers`
//! into grey variants (original, mirror image, and the mirror image blurred,
//! dimmed, at half scale, at JPEG 60, and all combined) and a `set.json`
//! holding, per variant, the line-fit truth and what OpenCV 5's stock
//! detector found. This module reads that set, matches any detector's
//! markers to the truth and sums up recall, centre error and false markers.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use messages::Marker;
use opencv::core;
use serde::Deserialize;

use crate::{
    Detector, Result, StockPass, TrackError, diagonal_intersection, quad_center, shortest_side,
};

/// Ids of `DICT_4X4_50` whose mirror image is a rotation of the code itself:
/// in an image, a mirrored one cannot be told from a printed one.
pub const MIRROR_SYMMETRIC_IDS: [u32; 4] = [8, 9, 17, 47];

/// One marker of the set: the truth's or OpenCV 5's.
#[derive(Debug, Clone, Deserialize)]
pub struct SetMarker {
    /// Its `DICT_4X4_50` id.
    pub id: u32,
    /// Corners in the variant's pixels.
    pub corners: [[f64; 2]; 4],
    /// Where the diagonals cross.
    pub center: [f64; 2],
    /// RMS distance of the edge points from the fitted edges (truth only);
    /// `None` when the fit failed: the marker counts for recall, not accuracy.
    #[serde(default)]
    pub fit_rms_px: Option<f64>,
}

impl SetMarker {
    /// Mean side length, pixels.
    pub fn side(&self) -> f64 {
        (0..4)
            .map(|k| {
                let (a, b) = (self.corners[k], self.corners[(k + 1) % 4]);
                (a[0] - b[0]).hypot(a[1] - b[1])
            })
            .sum::<f64>()
            / 4.0
    }
}

/// One image of the set.
#[derive(Debug, Clone, Deserialize)]
pub struct Variant {
    /// The PNG, relative to the set's directory.
    pub file: String,
    /// The photograph it was made from, relative to the data directory.
    pub photo: String,
    /// `original`, `mirror`, `mirror_blur`, ...
    pub variant: String,
    /// Whether the image is the photograph's mirror image.
    pub mirrored: bool,
    /// The photograph's `DICT_4X4_50` markers in this image.
    pub truth: Vec<SetMarker>,
    /// What OpenCV 5's stock pass found (on the pixels flipped back when mirrored).
    pub stock: Vec<SetMarker>,
    /// Boxes crowded with small markers of one id that are not all in the
    /// truth: a report of that id there that matches no truth marker is
    /// neither found nor false.
    #[serde(default)]
    pub ignore: Vec<Ignore>,
}

/// A crowded box (see [`Variant::ignore`]).
#[derive(Debug, Clone, Deserialize)]
pub struct Ignore {
    /// The id whose unlisted reports are not counted.
    pub id: u32,
    /// x0, y0, x1, y1 in the variant's pixels.
    pub r#box: [f64; 4],
}

impl Ignore {
    fn covers(&self, found: &Found) -> bool {
        let [x0, y0, x1, y1] = self.r#box;
        found.id == self.id
            && (x0..=x1).contains(&found.center[0])
            && (y0..=y1).contains(&found.center[1])
    }
}

/// The set as `real_markers.py` wrote it.
#[derive(Debug, Clone, Deserialize)]
pub struct RealSet {
    /// Version of the OpenCV that made the truth's seeds and the stock column.
    pub opencv: String,
    /// Every image.
    pub variants: Vec<Variant>,
    /// Where the set lives.
    #[serde(skip)]
    pub dir: PathBuf,
}

impl RealSet {
    /// Reads `DIR/set.json`; fails with [`TrackError::ReadSet`] or
    /// [`TrackError::ParseSet`].
    pub fn load(dir: &Path) -> Result<Self> {
        let path = dir.join("set.json");
        let text = std::fs::read_to_string(&path).map_err(|source| TrackError::ReadSet {
            path: path.clone(),
            source,
        })?;
        let mut set: Self =
            serde_json::from_str(&text).map_err(|source| TrackError::ParseSet { path, source })?;
        set.dir = dir.to_path_buf();
        Ok(set)
    }
}

/// What a detector reported, reduced to what the score needs.
#[derive(Debug, Clone, Copy)]
pub struct Found {
    /// Its id.
    pub id: u32,
    /// Whether it said mirror-reversed; `None` for a detector that cannot tell.
    pub mirrored: Option<bool>,
    /// Its centre.
    pub center: [f64; 2],
}

impl From<&Marker> for Found {
    fn from(m: &Marker) -> Self {
        Self {
            id: m.id,
            mirrored: Some(m.mirrored != 0),
            center: m.center,
        }
    }
}

impl From<&SetMarker> for Found {
    fn from(m: &SetMarker) -> Self {
        Self {
            id: m.id,
            mirrored: None,
            center: m.center,
        }
    }
}

/// Index of the truth marker a detection is, if any: same id, centre within
/// a quarter of the marker's side (at least 2 px).
fn matching(truth: &[SetMarker], found: &Found) -> Option<usize> {
    truth
        .iter()
        .enumerate()
        .filter(|(_, t)| t.id == found.id)
        .map(|(i, t)| {
            let d = (t.center[0] - found.center[0]).hypot(t.center[1] - found.center[1]);
            (i, d, (0.25 * t.side()).max(2.0))
        })
        .filter(|(_, d, limit)| d <= limit)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _, _)| i)
}

/// A detector's figures over some images.
#[derive(Debug, Clone, Default)]
pub struct Score {
    /// Truth markers in the images.
    pub markers: usize,
    /// Of those, found.
    pub found: usize,
    /// Markers OpenCV 5's stock pass found.
    pub reference: usize,
    /// Of those, found by this detector too.
    pub found_of_reference: usize,
    /// Centre errors of the found markers whose truth fit is good, pixels.
    pub center_errors: Vec<f64>,
    /// Reports that are no truth marker: (image, id, centre).
    pub false_markers: Vec<(String, u32, [f64; 2])>,
    /// Found markers whose mirrored flag is wrong (ids that can tell only).
    pub wrong_flags: usize,
    /// Markers OpenCV 5 found and this detector did not: (image, id, centre).
    pub missed: Vec<(String, u32, [f64; 2])>,
}

impl Score {
    /// Adds one image's detections.
    pub fn add(&mut self, variant: &Variant, found: &[Found]) {
        let truth = &variant.truth;
        let mut hit = vec![false; truth.len()];
        for f in found {
            let Some(i) = matching(truth, f) else {
                if variant.ignore.iter().any(|g| g.covers(f)) {
                    continue;
                }
                self.false_markers
                    .push((variant.file.clone(), f.id, f.center));
                continue;
            };
            if hit[i] {
                // A second report of the same marker.
                self.false_markers
                    .push((variant.file.clone(), f.id, f.center));
                continue;
            }
            hit[i] = true;
            let t = &truth[i];
            if t.fit_rms_px.is_some() {
                self.center_errors
                    .push((t.center[0] - f.center[0]).hypot(t.center[1] - f.center[1]));
            }
            if let Some(m) = f.mirrored
                && m != variant.mirrored
                && !MIRROR_SYMMETRIC_IDS.contains(&f.id)
            {
                self.wrong_flags += 1;
            }
        }
        self.markers += truth.len();
        self.found += hit.iter().filter(|&&h| h).count();
        let reference: Vec<usize> = variant
            .stock
            .iter()
            .filter_map(|s| matching(truth, &Found::from(s)))
            .collect();
        self.reference += reference.len();
        for &i in &reference {
            if hit[i] {
                self.found_of_reference += 1;
            } else {
                self.missed
                    .push((variant.file.clone(), truth[i].id, truth[i].center));
            }
        }
    }

    /// Median and largest centre error, pixels.
    pub fn center_error(&self) -> (f64, f64) {
        let mut e = self.center_errors.clone();
        e.sort_by(f64::total_cmp);
        if e.is_empty() {
            return (f64::NAN, f64::NAN);
        }
        let mid = e.len() / 2;
        let median = if e.len() % 2 == 1 {
            e[mid]
        } else {
            0.5 * (e[mid - 1] + e[mid])
        };
        (median, e[e.len() - 1])
    }
}

/// Scores per variant name, and over all images.
#[derive(Debug, Clone, Default)]
pub struct Report {
    /// Per variant name, in the set's order.
    pub per_variant: BTreeMap<String, Score>,
    /// Over every image.
    pub all: Score,
}

impl Report {
    /// Adds one image's detections.
    pub fn add(&mut self, variant: &Variant, found: &[Found]) {
        self.per_variant
            .entry(variant.variant.clone())
            .or_default()
            .add(variant, found);
        self.all.add(variant, found);
    }
}

/// OpenCV's stock pass ([`StockPass`]); on a mirrored image it runs on the
/// pixels flipped back, as the set's OpenCV 5 column does.
pub fn stock_pass(stock: &StockPass, image: &core::Mat, mirrored: bool) -> Result<Vec<Found>> {
    let mut flipped = core::Mat::default();
    let readable = if mirrored {
        core::flip(image, &mut flipped, 1)?;
        &flipped
    } else {
        image
    };
    let width = f64::from(core::MatTraitConst::cols(image));
    let mut out = Vec::new();
    for (id, quad) in stock.detect(readable)? {
        let mut c: Vec<[f64; 2]> = quad
            .iter()
            .map(|p| [f64::from(p.x), f64::from(p.y)])
            .collect();
        if mirrored {
            for p in &mut c {
                p[0] = width - 1.0 - p[0];
            }
        }
        if let Some(center) = diagonal_intersection(&c) {
            out.push(Found {
                id,
                mirrored: None,
                center,
            });
        }
    }
    Ok(out)
}

/// How the detector's candidates centred within 4 px of `center` read, in
/// words: why a marker was missed, or what a false report was read from.
pub fn readings_near(
    detector: &mut Detector,
    image: &core::Mat,
    center: [f64; 2],
) -> Result<Vec<String>> {
    Ok(detector
        .candidates(image)?
        .into_iter()
        .filter(|(q, _)| {
            let (x, y) = quad_center(q);
            (f64::from(x) - center[0]).hypot(f64::from(y) - center[1]) < 4.0
        })
        .map(|(q, reading)| {
            let what = match reading {
                Ok(d) => format!("read id {} ({} bits corrected)", d.id, d.errors),
                Err(refusal) => format!("{refusal:?}"),
            };
            format!("{what}, side {:.1}", shortest_side(&q))
        })
        .collect())
}

/// A plain-text table of detectors side by side: per variant and over all
/// images, markers found (of the truth and of OpenCV 5's finds), median and
/// largest centre error, false markers and wrong mirrored flags.
pub fn table(columns: &[(&str, &Report)]) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<16} {:<10} {:>11} {:>12} {:>8} {:>8} {:>6} {:>6}",
        "variant", "detector", "found", "of OpenCV 5", "median", "max", "false", "flag"
    );
    let Some((_, first)) = columns.first() else {
        return out;
    };
    let mut rows: Vec<(&str, Vec<&Score>)> = first
        .per_variant
        .keys()
        .map(|k| {
            (
                k.as_str(),
                columns
                    .iter()
                    .map(|(_, r)| r.per_variant.get(k).unwrap_or(&r.all))
                    .collect(),
            )
        })
        .collect();
    rows.push(("all", columns.iter().map(|(_, r)| &r.all).collect()));
    for (variant, scores) in rows {
        for ((name, _), s) in columns.iter().zip(scores) {
            let (median, max) = s.center_error();
            let _ = writeln!(
                out,
                "{:<16} {:<10} {:>5}/{:<5} {:>5}/{:<6} {:>8.3} {:>8.3} {:>6} {:>6}",
                variant,
                name,
                s.found,
                s.markers,
                s.found_of_reference,
                s.reference,
                median,
                max,
                s.false_markers.len(),
                s.wrong_flags
            );
        }
    }
    out
}
