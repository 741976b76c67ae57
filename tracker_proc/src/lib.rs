//! ArUco detection that also finds markers seen mirror-reversed.
//!
//! A reflected marker does not decode with the stock dictionary (most
//! `DICT_4X4_50` codes are not found at all when flipped). We build one
//! dictionary holding the 50 codes and their mirror images, so a single
//! `detectMarkers` pass per image finds both kinds and the index says which.
//! A mirror image too close (Hamming distance, any rotation) to another code
//! would make the flag unreliable; such codes are left out and reported by
//! [`Detector::mirror_ambiguous_ids`]. Corners are refined to sub-pixel; the
//! centre is the intersection of the diagonals.
//!
//! ```no_run
//! let mut detector = tracker_proc::Detector::new(true)?;
//! let image = opencv::imgcodecs::imread("frame_left.png", opencv::imgcodecs::IMREAD_GRAYSCALE)?;
//! for m in detector.detect(&image)? {
//!     println!("id {} mirrored {} at {:?}", m.id, m.mirrored, m.center);
//! }
//! # Ok::<(), anyhow::Error>(())
//! ```

pub mod step;

pub use step::{Tracked, Tracker};

use anyhow::{Context, Result};
use messages::Marker;
use opencv::aruco;
use opencv::core::{self, Mat, Point2f, Ptr, Vector};
use opencv::prelude::*;

/// Markers of the stock dictionary.
const BASE_MARKERS: i32 = 50;
/// Smallest Hamming distance (over rotations) a mirror image must keep from
/// every other code. The combined dictionary corrects no bits, so with 2 a
/// single bit error yields no code rather than a wrong one. (Keeping the
/// stock 1-bit correction would need 3 and lose 23 of the 50 ids.)
const MIN_MIRROR_DISTANCE: i32 = 2;

/// An ArUco detector over `DICT_4X4_50`, optionally with mirror images.
pub struct Detector {
    dictionary: Ptr<aruco::Dictionary>,
    params: Ptr<aruco::DetectorParameters>,
    /// Combined index -> (id, mirrored).
    index: Vec<(u32, bool)>,
    ambiguous: Vec<u32>,
}

impl Detector {
    /// A detector; with `mirrored`, it also finds mirror-reversed markers.
    pub fn new(mirrored: bool) -> Result<Self> {
        let base =
            aruco::get_predefined_dictionary(aruco::PREDEFINED_DICTIONARY_NAME::DICT_4X4_50)?;
        let marker_size = base.marker_size();
        let base_bytes = base.bytes_list();
        let mut index: Vec<(u32, bool)> = (0..BASE_MARKERS as u32).map(|id| (id, false)).collect();
        let mut ambiguous = Vec::new();
        let mut rows = Vector::<Mat>::new();
        rows.push(
            base_bytes
                .row_range(&core::Range::new(0, BASE_MARKERS)?)?
                .try_clone()?,
        );
        if mirrored {
            let mut accepted: Vec<Mat> = Vec::new();
            for id in 0..BASE_MARKERS {
                let bits = aruco::Dictionary::get_bits_from_byte_list(
                    &base_bytes.row(id)?.try_clone()?,
                    marker_size,
                )?;
                let mut flipped = Mat::default();
                core::flip(&bits, &mut flipped, 1)?;
                let mut nearest = i32::MAX;
                for other in 0..BASE_MARKERS {
                    nearest = nearest.min(base.get_distance_to_id(&flipped, other, true)?);
                }
                for previous in &accepted {
                    let mut d = i32::MAX;
                    for r in 0..4 {
                        let mut rotated = previous.clone();
                        for _ in 0..r {
                            let mut t = Mat::default();
                            core::rotate(&rotated, &mut t, core::ROTATE_90_CLOCKWISE)?;
                            rotated = t;
                        }
                        d = d.min(core::norm2(
                            &flipped,
                            &rotated,
                            core::NORM_HAMMING,
                            &core::no_array(),
                        )? as i32);
                    }
                    nearest = nearest.min(d);
                }
                if nearest < MIN_MIRROR_DISTANCE {
                    ambiguous.push(id as u32);
                    continue;
                }
                rows.push(aruco::Dictionary::get_byte_list_from_bits(&flipped)?);
                accepted.push(flipped);
                index.push((id as u32, true));
            }
        }
        let mut bytes = Mat::default();
        core::vconcat(&rows, &mut bytes)?;
        let correction = if mirrored {
            0
        } else {
            base.max_correction_bits()
        };
        let dictionary = Ptr::new(aruco::Dictionary::new(&bytes, marker_size, correction)?);
        let mut params = aruco::DetectorParameters::create()?;
        params.set_corner_refinement_method(aruco::CornerRefineMethod::CORNER_REFINE_SUBPIX as i32);
        Ok(Self {
            dictionary,
            params,
            index,
            ambiguous,
        })
    }

    /// Ids whose mirror image is left out (the mirrored flag would be unreliable).
    pub fn mirror_ambiguous_ids(&self) -> &[u32] {
        &self.ambiguous
    }

    /// Finds the markers of a mono8 (or BGR8) image.
    pub fn detect(&mut self, image: &impl core::ToInputArray) -> Result<Vec<Marker>> {
        let mut corners = Vector::<Vector<Point2f>>::new();
        let mut ids = Vector::<i32>::new();
        let mut rejected = Vector::<Vector<Point2f>>::new();
        aruco::detect_markers(
            image,
            &self.dictionary,
            &mut corners,
            &mut ids,
            &self.params,
            &mut rejected,
        )
        .context("ArUco detection")?;
        let mut out = Vec::with_capacity(ids.len());
        for (i, quad) in ids.iter().zip(corners.iter()) {
            let Some(&(id, mirrored)) = usize::try_from(i).ok().and_then(|i| self.index.get(i))
            else {
                continue;
            };
            let c: Vec<[f64; 2]> = quad
                .iter()
                .map(|p| [f64::from(p.x), f64::from(p.y)])
                .collect();
            if c.len() != 4 {
                continue;
            }
            let Some(center) = diagonal_intersection(&c) else {
                continue;
            };
            let mut flat = [0.0; 8];
            for (k, p) in c.iter().enumerate() {
                flat[2 * k] = p[0];
                flat[2 * k + 1] = p[1];
            }
            out.push(Marker {
                id,
                mirrored: u32::from(mirrored),
                corners: flat,
                center,
            });
        }
        Ok(out)
    }
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
