//! Reading a candidate quadrilateral's code: its cells, checks that it looks
//! like a printed marker, and the nearest code of `DICT_4X4_50`, printed or
//! mirror-reversed, within that code's own safe correction radius.
//!
//! OpenCV corrects the same number of bits for every code of a dictionary.
//! With the mirror images added, codes sit at different distances from
//! their nearest neighbour (2 to 5 bits), so each code gets the radius its
//! own neighbourhood allows: `(distance - 1) / 2` bits. Within it, the read
//! is nearer to this code than to any other, in any rotation.
//!
//! Other 4x4 dictionaries print codes that are not ours: `DICT_4X4_100` to
//! `_1000` beyond id 49, AprilTag 16h5, and their mirror images. Most of our
//! codes lie one bit from one of those, so correcting that bit would report
//! a foreign marker as ours. [`Correction::SparingForeign`] (the default)
//! corrects a code only where no foreign code lies within the radius.

use std::collections::HashSet;

use opencv::aruco;
use opencv::core::{self, Mat, Point2f, Size, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use crate::Result;

/// Cells per side: 4 code cells and a black border cell each side.
pub(crate) const CELLS: usize = 6;
/// Pixels per cell in the rectified candidate.
const CELL_PX: i32 = 6;
/// Pixels of each cell's edge left out when averaging (perspective and blur
/// smear the neighbours' ink into it).
const CELL_MARGIN_PX: i32 = 1;
/// Below this [`Decoded::margin`] a read is checked against the larger
/// families ([`CodeBook::larger_family`]): a 6x6 marker seen on a 4x4 grid
/// mixes its cells, so some of ours come out near grey (the five drawn 6x6
/// markers our reading took for codes had margins of 0.05 to 0.08), while a
/// clean two-tone read spares the check's three warps.
const LARGER_FAMILY_BELOW_MARGIN: f64 = 0.2;
/// Pixels per cell in OpenCV's reading ([`CodeBook::read_as_opencv`]): its
/// `perspectiveRemovePixelPerCell` default.
const OPENCV_CELL_PX: i32 = 4;
/// White border cells OpenCV's reading allows: its
/// `maxErroneousBitsInBorderRate` default, 35% of 20.
const OPENCV_BORDER_ERRORS: u32 = 7;

/// A 4x4 code, row-major, `true` for a white cell.
pub type Bits = [bool; 16];

/// Rotates a code 90 degrees clockwise.
fn rotate(b: &Bits) -> Bits {
    let mut out = [false; 16];
    for r in 0..4 {
        for c in 0..4 {
            out[c * 4 + (3 - r)] = b[r * 4 + c];
        }
    }
    out
}

/// Mirrors a code left to right.
fn flip(b: &Bits) -> Bits {
    let mut out = [false; 16];
    for r in 0..4 {
        for c in 0..4 {
            out[r * 4 + (3 - c)] = b[r * 4 + c];
        }
    }
    out
}

fn hamming(a: &Bits, b: &Bits) -> u32 {
    a.iter().zip(b).filter(|(x, y)| x != y).count() as u32
}

/// One code of the book.
#[derive(Debug, Clone)]
struct Entry {
    id: u32,
    mirrored: bool,
    /// The code in its four rotations: `rotations[k]` is the code turned
    /// k times 90 degrees clockwise.
    rotations: [Bits; 4],
    /// Bits this code may correct.
    radius: u32,
}

/// A decoded candidate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decoded {
    /// `DICT_4X4_50` id.
    pub id: u32,
    /// Read mirror-reversed.
    pub mirrored: bool,
    /// Quarter turns clockwise from the candidate's corner order to the code's.
    pub rotation: usize,
    /// Bits corrected.
    pub errors: u32,
    /// Smallest distance of a code cell's brightness from the threshold, as
    /// a fraction of the black-to-white contrast: low when a cell is neither.
    pub margin: f64,
    /// The lead of this code over the next code or rotation.
    pub gap: f64,
    /// Black-to-white contrast, grey levels.
    pub contrast: f64,
}

/// Length of a quadrilateral's shortest side, pixels.
pub fn shortest_side(q: &[Point2f; 4]) -> f32 {
    (0..4)
        .map(|k| {
            let (a, b) = (q[k], q[(k + 1) % 4]);
            (a.x - b.x).hypot(a.y - b.y)
        })
        .fold(f32::INFINITY, f32::min)
}

/// Mean of a quadrilateral's corners.
pub fn quad_center(q: &[Point2f; 4]) -> (f32, f32) {
    let s = q
        .iter()
        .fold((0.0f32, 0.0f32), |a, p| (a.0 + p.x, a.1 + p.y));
    (s.0 / 4.0, s.1 / 4.0)
}

/// What reading a candidate gave: a marker, or why not.
pub type Reading = std::result::Result<Decoded, Refusal>;

/// Why a candidate was not read as a marker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Refusal {
    /// Too small: this many pixels on its shortest side.
    Small(f64),
    /// Too little contrast between the border and the brightest cell.
    Contrast(f64),
    /// This many border cells read white.
    Border(u32),
    /// A code cell this close to the threshold (fraction of the contrast).
    Margin(f64),
    /// The best code needs this many bits corrected, more than its radius.
    NoCode(u32),
    /// A foreign code (another 4x4 dictionary's) explains the cells best.
    Foreign,
    /// The best code beats the next one by only this much.
    Ambiguous(f64),
}

/// How many bits a code may correct.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Correction {
    /// None: exact codes only.
    None,
    /// Half the distance to the nearest other code of the book (normal and
    /// mirrored, any rotation), rounded down, at most `max` bits.
    OwnCodes {
        /// Cap on the radius.
        max: u32,
    },
    /// As [`Correction::OwnCodes`], and less than the distance to the nearest
    /// code of another 4x4 dictionary, so that a cleanly printed foreign
    /// marker is never read as one of ours.
    SparingForeign {
        /// Cap on the radius.
        max: u32,
    },
}

/// Checks that make a quadrilateral a printed marker rather than a pattern
/// that happens to read as a code.
#[derive(Debug, Clone, Copy)]
pub struct Checks {
    /// Border cells (of 20) that may read white.
    pub border_errors: u32,
    /// Level (fraction of the contrast above black) above which a border
    /// cell reads white: well above half, since on a small or steeply seen
    /// marker blur spreads the white code cells into the thin border.
    pub border_level: f64,
    /// Smallest white-to-black contrast, grey levels.
    pub min_contrast: f64,
    /// Shortest side, pixels: below one pixel per cell the cells cannot be
    /// told apart, and blobs read as codes.
    pub min_side: f64,
    /// Smallest [`Decoded::margin`] accepted.
    pub min_margin: f64,
    /// Smallest lead of the best code over the next code or rotation (sum of
    /// the cells' signed levels, each in contrast units).
    pub min_gap: f64,
    /// Largest [`crate::pattern::misfit`] of a read marker from its code,
    /// on its final corners. On the real set printed markers reach 0.135
    /// and the fragile-glass pictogram read as id 17 lies at 0.17 to 0.18;
    /// on rendered frames (motion blur, noise) markers stay under 0.11.
    pub max_misfit: f64,
}

impl Default for Checks {
    fn default() -> Self {
        Self {
            border_errors: 1,
            border_level: 0.7,
            min_contrast: 20.0,
            min_side: 6.0,
            min_margin: 0.05,
            min_gap: 0.5,
            max_misfit: 0.155,
        }
    }
}

/// The codes of a predefined 4x4 dictionary, in id order.
fn codes(name: aruco::PREDEFINED_DICTIONARY_NAME) -> Result<Vec<Bits>> {
    let dictionary = aruco::get_predefined_dictionary(name)?;
    let bytes = dictionary.bytes_list();
    (0..bytes.rows())
        .map(|id| {
            let m = aruco::Dictionary::get_bits_from_byte_list(&bytes.row(id)?, 4)?;
            let mut bits = [false; 16];
            for (k, b) in bits.iter_mut().enumerate() {
                *b = *m.at_2d::<u8>(k as i32 / 4, k as i32 % 4)? != 0;
            }
            Ok(bits)
        })
        .collect()
}

/// Codes of the larger marker families (5x5, 6x6, 7x7 ArUco and AprilTag
/// 25h9, 36h11), each in its four rotations and mirrored, as bit patterns
/// of the inner cells (row-major, bit k for cell k), per inner side.
fn larger_families() -> Result<Vec<(usize, HashSet<u64>)>> {
    use aruco::PREDEFINED_DICTIONARY_NAME::*;
    let mut out = Vec::new();
    for (side, names) in [
        (5, vec![DICT_5X5_1000, DICT_APRILTAG_25h9]),
        (6, vec![DICT_6X6_1000, DICT_APRILTAG_36h11]),
        (7, vec![DICT_7X7_1000]),
    ] {
        let mut set = HashSet::new();
        for name in names {
            let dictionary = aruco::get_predefined_dictionary(name)?;
            let bytes = dictionary.bytes_list();
            for id in 0..bytes.rows() {
                let m = aruco::Dictionary::get_bits_from_byte_list(&bytes.row(id)?, side as i32)?;
                let mut grid = vec![false; side * side];
                for (k, b) in grid.iter_mut().enumerate() {
                    *b = *m.at_2d::<u8>((k / side) as i32, (k % side) as i32)? != 0;
                }
                for mirrored in [false, true] {
                    let mut g: Vec<bool> = if mirrored {
                        (0..side * side)
                            .map(|k| grid[(k / side) * side + side - 1 - k % side])
                            .collect()
                    } else {
                        grid.clone()
                    };
                    for _ in 0..4 {
                        set.insert(pack(&g));
                        // Turned 90 degrees clockwise.
                        g = (0..side * side)
                            .map(|k| g[(side - 1 - k % side) * side + k / side])
                            .collect();
                    }
                }
            }
        }
        out.push((side, set));
    }
    Ok(out)
}

/// Cells as bits, cell k at bit k.
fn pack(cells: &[bool]) -> u64 {
    cells
        .iter()
        .enumerate()
        .fold(0, |acc, (k, &w)| acc | (u64::from(w) << k))
}

/// 4x4 codes printed by other dictionaries (`DICT_4X4_1000` beyond id 49,
/// which `_100` and `_250` share, and AprilTag 16h5), and their mirror images.
fn foreign_codes() -> Result<Vec<Bits>> {
    let mut out: Vec<Bits> = codes(aruco::PREDEFINED_DICTIONARY_NAME::DICT_4X4_1000)?
        .into_iter()
        .skip(50)
        .collect();
    out.extend(codes(
        aruco::PREDEFINED_DICTIONARY_NAME::DICT_APRILTAG_16h5,
    )?);
    let mirrored: Vec<Bits> = out.iter().map(flip).collect();
    out.extend(mirrored);
    Ok(out)
}

/// The codes of `DICT_4X4_50`, optionally with their mirror images, each with
/// its correction radius.
#[derive(Debug, Clone)]
pub struct CodeBook {
    entries: Vec<Entry>,
    ambiguous: Vec<u32>,
    /// Foreign codes (see [`Correction::SparingForeign`]): a read nearer to
    /// one of these than to any of ours is refused.
    decoys: Vec<Bits>,
    /// Larger families' codes by inner side (see [`larger_families`]): a
    /// candidate that OpenCV's reading takes for one of them is refused.
    larger: Vec<(usize, HashSet<u64>)>,
}

impl CodeBook {
    /// The book; with `mirrored`, mirror images too.
    pub fn new(mirrored: bool, correction: Correction) -> Result<Self> {
        let mut entries = Vec::new();
        let mut ambiguous = Vec::new();
        for (id, bits) in codes(aruco::PREDEFINED_DICTIONARY_NAME::DICT_4X4_50)?
            .into_iter()
            .enumerate()
        {
            let rotations = |b: Bits| {
                let r1 = rotate(&b);
                let r2 = rotate(&r1);
                [b, r1, r2, rotate(&r2)]
            };
            let normal = rotations(bits);
            entries.push(Entry {
                id: id as u32,
                mirrored: false,
                rotations: normal,
                radius: 0,
            });
            if mirrored {
                let flipped = rotations(flip(&bits));
                if normal.iter().any(|r| *r == flipped[0]) {
                    // The mirror image is the code turned: a mirrored one reads
                    // as printed, and the flag cannot be told.
                    ambiguous.push(id as u32);
                } else {
                    entries.push(Entry {
                        id: id as u32,
                        mirrored: true,
                        rotations: flipped,
                        radius: 0,
                    });
                }
            }
        }
        let distances: Vec<u32> = entries
            .iter()
            .enumerate()
            .map(|(i, e)| {
                let own = (1..4)
                    .map(|r| hamming(&e.rotations[0], &e.rotations[r]))
                    .min()
                    .unwrap_or(16);
                entries
                    .iter()
                    .enumerate()
                    .filter(|(j, _)| *j != i)
                    .flat_map(|(_, o)| o.rotations.iter().map(|r| hamming(&e.rotations[0], r)))
                    .min()
                    .unwrap_or(16)
                    .min(own)
            })
            .collect();
        let foreign = match correction {
            Correction::SparingForeign { .. } => foreign_codes()?,
            _ => Vec::new(),
        };
        for (e, d) in entries.iter_mut().zip(distances) {
            let own = d.saturating_sub(1) / 2;
            e.radius = match correction {
                Correction::None => 0,
                Correction::OwnCodes { max } => own.min(max),
                Correction::SparingForeign { max } => {
                    let nearest = foreign
                        .iter()
                        .flat_map(|f| e.rotations.iter().map(move |r| hamming(r, f)))
                        .min()
                        .unwrap_or(16);
                    own.min(max).min(nearest.saturating_sub(1))
                }
            };
        }
        let decoys = foreign
            .iter()
            .flat_map(|f| {
                let r1 = rotate(f);
                let r2 = rotate(&r1);
                [*f, r1, r2, rotate(&r2)]
            })
            .collect();
        Ok(Self {
            entries,
            ambiguous,
            decoys,
            larger: larger_families()?,
        })
    }

    /// The code of `id`, mirror-reversed with `mirrored`, upright: as a
    /// [`Decoded`] marker's cells lie once its corners are turned by its
    /// rotation.
    pub fn code(&self, id: u32, mirrored: bool) -> Option<Bits> {
        self.entries
            .iter()
            .find(|e| e.id == id && e.mirrored == mirrored)
            .map(|e| e.rotations[0])
    }

    /// Ids whose mirror image is a rotation of the code: found either way,
    /// reported as printed.
    pub fn mirror_symmetric_ids(&self) -> &[u32] {
        &self.ambiguous
    }

    /// Correction radius of each (id, mirrored) in the book.
    pub fn radii(&self) -> Vec<(u32, bool, u32)> {
        self.entries
            .iter()
            .map(|e| (e.id, e.mirrored, e.radius))
            .collect()
    }

    /// The code that best explains the cells' brightness: each code cell's
    /// signed distance from the threshold (as a fraction of the contrast) is
    /// added where the code has white and subtracted where it has black, so
    /// clear cells weigh more than doubtful ones. Accepted when the best is
    /// one of ours (not a foreign code), its hard-read errors lie within its
    /// radius, and it beats every other code and rotation by `min_gap`.
    fn identify(
        &self,
        levels: &[f64; 16],
        min_gap: f64,
    ) -> std::result::Result<(u32, bool, usize, u32, f64), Refusal> {
        let score = |code: &Bits| -> f64 {
            levels
                .iter()
                .zip(code)
                .map(|(l, &white)| if white { *l } else { -*l })
                .sum()
        };
        let mut best: Option<(f64, usize, usize)> = None;
        let mut second = f64::NEG_INFINITY;
        for (i, e) in self.entries.iter().enumerate() {
            for (r, code) in e.rotations.iter().enumerate() {
                let s = score(code);
                match best {
                    Some((b, _, _)) if s <= b => second = second.max(s),
                    _ => {
                        if let Some((b, _, _)) = best {
                            second = second.max(b);
                        }
                        best = Some((s, i, r));
                    }
                }
            }
        }
        let Some((best_score, i, r)) = best else {
            return Err(Refusal::NoCode(16));
        };
        let foreign = self
            .decoys
            .iter()
            .map(score)
            .fold(f64::NEG_INFINITY, f64::max);
        if foreign >= best_score {
            return Err(Refusal::Foreign);
        }
        second = second.max(foreign);
        let e = &self.entries[i];
        let bits: Bits = std::array::from_fn(|k| levels[k] > 0.0);
        let errors = hamming(&bits, &e.rotations[r]);
        if errors > e.radius {
            return Err(Refusal::NoCode(errors));
        }
        if best_score - second < min_gap {
            return Err(Refusal::Ambiguous(best_score - second));
        }
        Ok((e.id, e.mirrored, r, errors, best_score - second))
    }

    /// Reads the candidate with corners `quad` (OpenCV's candidate order) in
    /// the grey `image`: the marker, or why it is none of the book's.
    pub fn read(
        &self,
        image: &impl core::ToInputArray,
        quad: &[Point2f; 4],
        checks: &Checks,
    ) -> Result<Reading> {
        let shortest = f64::from(shortest_side(quad));
        if shortest < checks.min_side {
            return Ok(Err(Refusal::Small(shortest)));
        }
        let cells = rectify(image, quad)?;
        let is_border = |k: usize| {
            let (r, c) = (k / CELLS, k % CELLS);
            r == 0 || c == 0 || r == CELLS - 1 || c == CELLS - 1
        };
        let code_cells = || (1..CELLS - 1).flat_map(|r| (1..CELLS - 1).map(move |c| r * CELLS + c));
        // Black is the border's level (its median cell, robust to a cell or two
        // of glare); white the brightest code cell's.
        let mut border: Vec<f64> = (0..CELLS * CELLS)
            .filter(|&k| is_border(k))
            .map(|k| cells[k])
            .collect();
        border.sort_by(f64::total_cmp);
        let black = border[border.len() / 2];
        let white = code_cells().map(|k| cells[k]).fold(f64::MIN, f64::max);
        let contrast = white - black;
        if contrast < checks.min_contrast {
            return Ok(Err(Refusal::Contrast(contrast)));
        }
        let threshold = 0.5 * (black + white);
        let border_white = border
            .iter()
            .filter(|&&m| m > black + checks.border_level * contrast)
            .count() as u32;
        if border_white > checks.border_errors {
            return Ok(Err(Refusal::Border(border_white)));
        }
        let mut levels = [0.0; 16];
        for (i, k) in code_cells().enumerate() {
            levels[i] = (cells[k] - threshold) / contrast;
        }
        let margin = levels.iter().fold(f64::MAX, |m, l| m.min(l.abs()));
        if margin < checks.min_margin {
            return Ok(Err(Refusal::Margin(margin)));
        }
        let identified = self.identify(&levels, checks.min_gap);
        if identified.is_ok()
            && margin < LARGER_FAMILY_BELOW_MARGIN
            && self.larger_family(image, quad)?
        {
            return Ok(Err(Refusal::Foreign));
        }
        Ok(
            identified.map(|(id, mirrored, rotation, errors, gap)| Decoded {
                id,
                mirrored,
                rotation,
                errors,
                margin,
                gap,
                contrast,
            }),
        )
    }

    /// Whether OpenCV's reading takes the candidate for a marker of a larger
    /// family (a 6x6 marker, a ChArUco board's): read as 4x4 cells, such a
    /// marker can land on one of our codes.
    fn larger_family(&self, image: &impl core::ToInputArray, quad: &[Point2f; 4]) -> Result<bool> {
        for (side, codes) in &self.larger {
            let cells = side + 2;
            if let Some((white, _)) = opencv_cells(image, quad, cells)?
                && 100 * border_whites(&white, cells) <= 35 * (4 * cells as u32 - 4)
            {
                let inner: Vec<bool> = (0..side * side)
                    .map(|k| white[(k / side + 1) * cells + k % side + 1])
                    .collect();
                if codes.contains(&pack(&inner)) {
                    return Ok(true);
                }
            }
        }
        Ok(false)
    }

    /// The code (ours or foreign, any rotation) that the cells' averages
    /// lean to most, however little.
    fn favoured(&self, cells: &Cells) -> Bits {
        let border = |k: usize| {
            let (r, c) = (k / CELLS, k % CELLS);
            r == 0 || c == 0 || r == CELLS - 1 || c == CELLS - 1
        };
        let mut edge: Vec<f64> = (0..CELLS * CELLS)
            .filter(|&k| border(k))
            .map(|k| cells[k])
            .collect();
        edge.sort_by(f64::total_cmp);
        let code: [f64; 16] = std::array::from_fn(|i| cells[(i / 4 + 1) * CELLS + i % 4 + 1]);
        let white = code.iter().copied().fold(f64::MIN, f64::max);
        let threshold = 0.5 * (edge[edge.len() / 2] + white);
        let score = |bits: &Bits| -> f64 {
            code.iter()
                .zip(bits)
                .map(|(l, &w)| if w { l - threshold } else { threshold - l })
                .sum()
        };
        self.entries
            .iter()
            .flat_map(|e| e.rotations.iter())
            .chain(self.decoys.iter())
            .copied()
            .max_by(|a, b| score(a).total_cmp(&score(b)))
            .unwrap_or([false; 16])
    }

    /// Reads a candidate the way OpenCV's stock pass does, with its
    /// defaults: warped to 4 px a cell by nearest pixel, one Otsu threshold,
    /// a cell white when most of its pixels are, up to 7 of the 20 border
    /// cells white, an exact code; and the cells' averages must lean to the
    /// same code, and no larger family may claim the candidate. A second
    /// look for our near misses only: on a blurred marker of 8 px or a
    /// steeply seen one, blur spreads the white cells into the thin border
    /// and leaves cell averages at the threshold, where OpenCV's reading of
    /// whole pixels still lands on the code.
    pub fn read_as_opencv(
        &self,
        image: &impl core::ToInputArray,
        quad: &[Point2f; 4],
        checks: &Checks,
    ) -> Result<Reading> {
        let shortest = f64::from(shortest_side(quad));
        if shortest < checks.min_side {
            return Ok(Err(Refusal::Small(shortest)));
        }
        let Some((white, contrast)) = opencv_cells(image, quad, CELLS)? else {
            return Ok(Err(Refusal::Contrast(0.0)));
        };
        if contrast < checks.min_contrast {
            return Ok(Err(Refusal::Contrast(contrast)));
        }
        let border_white = border_whites(&white, CELLS);
        if border_white > OPENCV_BORDER_ERRORS {
            return Ok(Err(Refusal::Border(border_white)));
        }
        let bits: Bits = std::array::from_fn(|i| white[(i / 4 + 1) * CELLS + i % 4 + 1]);
        if self.decoys.contains(&bits) {
            return Ok(Err(Refusal::Foreign));
        }
        let found = self.entries.iter().find_map(|e| {
            e.rotations
                .iter()
                .position(|r| *r == bits)
                .map(|rotation| (e, rotation))
        });
        let Some((e, rotation)) = found else {
            let nearest = self
                .entries
                .iter()
                .flat_map(|e| e.rotations.iter().map(|r| hamming(r, &bits)))
                .min()
                .unwrap_or(16);
            return Ok(Err(Refusal::NoCode(nearest)));
        };
        // Whole pixels by nearest neighbour can land on a code by chance (a
        // 6x6 marker's cells, a speck): the cells' averages must lean to the
        // same code, of every code and rotation, ours and foreign.
        if self.favoured(&rectify(image, quad)?) != bits {
            return Ok(Err(Refusal::Ambiguous(0.0)));
        }
        if self.larger_family(image, quad)? {
            return Ok(Err(Refusal::Foreign));
        }
        Ok(Ok(Decoded {
            id: e.id,
            mirrored: e.mirrored,
            rotation,
            errors: 0,
            // Read by whole pixels: no cell levels to give a margin or a lead.
            margin: 0.0,
            gap: 0.0,
            contrast,
        }))
    }
}

/// OpenCV's reading of a candidate as `cells` x `cells` cells (border
/// included): warped to [`OPENCV_CELL_PX`] pixels a cell by nearest pixel,
/// one Otsu threshold, a cell white when most of its pixels are. The cells
/// row-major and the contrast between the threshold's two classes; `None`
/// when the threshold left one class empty.
fn opencv_cells(
    image: &impl core::ToInputArray,
    quad: &[Point2f; 4],
    cells: usize,
) -> Result<Option<(Vec<bool>, f64)>> {
    let n = cells as i32 * OPENCV_CELL_PX;
    // As OpenCV: the corners on the outer pixels' centres, out of the image black.
    let warped = warp_square(
        image,
        quad,
        (0.0, (n - 1) as f32),
        n,
        imgproc::INTER_NEAREST,
        core::BORDER_CONSTANT,
    )?;
    let mut binary = Mat::default();
    let threshold = imgproc::threshold(
        &warped,
        &mut binary,
        125.0,
        255.0,
        imgproc::THRESH_BINARY | imgproc::THRESH_OTSU,
    )?;
    // The warp is a new, continuous Mat: its bytes row after row. White is
    // above the threshold, as in `binary`.
    let pixels = warped.data_bytes()?;
    let is_white = |v: u8| f64::from(v) > threshold;
    let (mut sums, mut counts) = ([0.0f64; 2], [0u32; 2]);
    for &v in pixels {
        let k = usize::from(is_white(v));
        sums[k] += f64::from(v);
        counts[k] += 1;
    }
    if counts.contains(&0) {
        return Ok(None);
    }
    let contrast = sums[1] / f64::from(counts[1]) - sums[0] / f64::from(counts[0]);
    let (n, px) = (n as usize, OPENCV_CELL_PX as usize);
    let mut on = vec![0usize; cells * cells];
    for (i, &v) in pixels.iter().enumerate() {
        if is_white(v) {
            on[(i / n / px) * cells + (i % n) / px] += 1;
        }
    }
    let white = on.iter().map(|&o| 2 * o > px * px).collect();
    Ok(Some((white, contrast)))
}

/// The candidate warped to a square of 6x6 cells of `cell_px` pixels,
/// bilinearly, its corners on the square's outer pixel edges so that each
/// cell spans whole pixels.
pub(crate) fn warp_cells(
    image: &impl core::ToInputArray,
    quad: &[Point2f; 4],
    cell_px: i32,
) -> Result<Mat> {
    let n = CELLS as i32 * cell_px;
    warp_square(
        image,
        quad,
        (-0.5, n as f32 - 0.5),
        n,
        imgproc::INTER_LINEAR,
        core::BORDER_REPLICATE,
    )
}

/// The candidate warped to an `n` x `n` square whose corners land at
/// `corners.0` and `corners.1` on both axes.
fn warp_square(
    image: &impl core::ToInputArray,
    quad: &[Point2f; 4],
    (lo, hi): (f32, f32),
    n: i32,
    interpolation: i32,
    border: i32,
) -> Result<Mat> {
    let dst = Vector::<Point2f>::from_iter([
        Point2f::new(lo, lo),
        Point2f::new(hi, lo),
        Point2f::new(hi, hi),
        Point2f::new(lo, hi),
    ]);
    let src = Vector::<Point2f>::from_iter(quad.iter().copied());
    let transform = imgproc::get_perspective_transform(&src, &dst, core::DECOMP_LU)?;
    let mut warped = Mat::default();
    imgproc::warp_perspective(
        image,
        &mut warped,
        &transform,
        Size::new(n, n),
        interpolation,
        border,
        core::Scalar::default(),
    )?;
    Ok(warped)
}

/// White cells on the border of a `cells` x `cells` grid.
fn border_whites(white: &[bool], cells: usize) -> u32 {
    (0..cells * cells)
        .filter(|&k| {
            let (r, c) = (k / cells, k % cells);
            white[k] && (r == 0 || c == 0 || r == cells - 1 || c == cells - 1)
        })
        .count() as u32
}

/// Mean brightness of each of a candidate's 6x6 cells (border included),
/// row-major.
type Cells = [f64; CELLS * CELLS];

/// Warps the candidate to a square of 6x6 cells of `CELL_PX` pixels and
/// averages the inside of each cell.
fn rectify(image: &impl core::ToInputArray, quad: &[Point2f; 4]) -> Result<Cells> {
    let n = CELLS as i32 * CELL_PX;
    let warped = warp_cells(image, quad, CELL_PX)?;
    let mut sums = [0u32; CELLS * CELLS];
    let mut counts = [0u32; CELLS * CELLS];
    let keep = CELL_MARGIN_PX..CELL_PX - CELL_MARGIN_PX;
    for y in 0..n {
        if !keep.contains(&(y % CELL_PX)) {
            continue;
        }
        let row = warped.at_row::<u8>(y)?;
        for x in (0..n).filter(|x| keep.contains(&(x % CELL_PX))) {
            let k = (y / CELL_PX) as usize * CELLS + (x / CELL_PX) as usize;
            sums[k] += u32::from(row[x as usize]);
            counts[k] += 1;
        }
    }
    Ok(std::array::from_fn(|k| {
        f64::from(sums[k]) / f64::from(counts[k].max(1))
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radii_follow_the_distances_between_codes() {
        let stock = CodeBook::new(false, Correction::OwnCodes { max: 8 }).unwrap();
        // Stock DICT_4X4_50 codes are at least 4 bits apart (in any rotation):
        // 1 bit each, and 2 for id 23, whose nearest neighbour is 5 bits away.
        for (id, _, r) in stock.radii() {
            assert_eq!(r, if id == 23 { 2 } else { 1 }, "id {id}");
        }
        let capped = CodeBook::new(false, Correction::OwnCodes { max: 1 }).unwrap();
        assert!(capped.radii().iter().all(|&(_, _, r)| r == 1));
        let both = CodeBook::new(true, Correction::OwnCodes { max: 8 }).unwrap();
        assert_eq!(both.mirror_symmetric_ids(), &[8, 9, 17, 47]);
        assert_eq!(both.radii().len(), 96);
        let zero = both.radii().iter().filter(|r| r.2 == 0).count();
        assert!(zero > 0 && zero < 96, "{zero} codes with no correction");
        assert!(both.radii().iter().all(|&(_, _, r)| r <= 1));
    }

    /// A marker of OpenCV's drawing, `side` pixels, on white, mirrored when
    /// asked, and its outline as OpenCV's candidates give it (the outer
    /// pixels' centres, clockwise).
    fn drawn(
        name: aruco::PREDEFINED_DICTIONARY_NAME,
        id: i32,
        side: i32,
        mirrored: bool,
    ) -> (Mat, [Point2f; 4]) {
        let dictionary = aruco::get_predefined_dictionary(name).unwrap();
        let mut marker = Mat::default();
        aruco::draw_marker(&dictionary, id, side, &mut marker, 1).unwrap();
        if mirrored {
            let mut flipped = Mat::default();
            core::flip(&marker, &mut flipped, 1).unwrap();
            marker = flipped;
        }
        let pad = 8;
        let mut image = Mat::default();
        core::copy_make_border(
            &marker,
            &mut image,
            pad,
            pad,
            pad,
            pad,
            core::BORDER_CONSTANT,
            core::Scalar::all(255.0),
        )
        .unwrap();
        let (lo, hi) = (pad as f32, (pad + side - 1) as f32);
        let quad = [
            Point2f::new(lo, lo),
            Point2f::new(hi, lo),
            Point2f::new(hi, hi),
            Point2f::new(lo, hi),
        ];
        (image, quad)
    }

    #[test]
    fn opencv_reading_reads_opencv_markers_printed_and_mirrored_and_no_6x6_marker() {
        use aruco::PREDEFINED_DICTIONARY_NAME::{DICT_4X4_50, DICT_6X6_250};
        let book = CodeBook::new(true, Correction::None).unwrap();
        let checks = Checks::default();
        let symmetric = book.mirror_symmetric_ids().to_vec();
        for side in [12, 24] {
            for id in 0..50 {
                for mirrored in [false, true] {
                    let (image, quad) = drawn(DICT_4X4_50, id, side, mirrored);
                    let d = book
                        .read_as_opencv(&image, &quad, &checks)
                        .unwrap()
                        .unwrap_or_else(|r| {
                            panic!("id {id}, {side} px, mirrored {mirrored}: {r:?}")
                        });
                    assert_eq!(d.id, id as u32);
                    // A mirror-symmetric code mirrored is the code turned.
                    let ambiguous = symmetric.contains(&(id as u32));
                    if !(mirrored && ambiguous) {
                        assert_eq!(d.rotation, 0, "id {id}");
                    }
                    assert_eq!(d.mirrored, mirrored && !ambiguous, "id {id}");
                    // Our own reading agrees (no larger family claims it).
                    let ours = book.read(&image, &quad, &checks).unwrap();
                    assert_eq!(ours.map(|o| o.id), Ok(id as u32), "id {id}, {side} px");
                }
            }
        }
        // A 6x6 marker is refused wherever its own cells are 2 px or more;
        // below that OpenCV's reading lands on a 4x4 code for about 1 in 300
        // (our cell averages alone: none), which the detector lets through
        // only for near misses of its own reading.
        let mut small = 0;
        for side in 9..=32 {
            for id in 0..250 {
                let (image, quad) = drawn(DICT_6X6_250, id, side, false);
                let read = book.read_as_opencv(&image, &quad, &checks).unwrap();
                assert!(book.read(&image, &quad, &checks).unwrap().is_err());
                if side >= 16 {
                    assert!(read.is_err(), "6x6 id {id} at {side} px read as {read:?}");
                } else if read.is_ok() {
                    small += 1;
                }
            }
        }
        assert!(small <= 7 * 250 / 100, "{small} small 6x6 markers read");
    }

    #[test]
    fn rotate_four_times_is_identity_and_flip_twice_too() {
        let mut b = [false; 16];
        for k in [0, 3, 5, 6, 11] {
            b[k] = true;
        }
        assert_eq!(rotate(&rotate(&rotate(&rotate(&b)))), b);
        assert_ne!(rotate(&b), b);
        assert_eq!(flip(&flip(&b)), b);
    }
}
