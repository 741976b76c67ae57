//! Whether a read marker looks like a printed grid of cells.
//!
//! A pattern that is no marker can still read as a code: a pictogram in a
//! black square (a fragile-glass label) lands on a code when its shapes
//! happen to cover the right cells. What tells it apart is how it fills
//! them: a printed code is a grid of uniform cells, blurred by the lens;
//! a pictogram's curves cross the cells. [`misfit`] draws the code the
//! marker was read as, blurs it as much as fits best, lets the surroundings
//! blur in at a brightness of their own, and measures how far the image is
//! from it, in units of the black-to-white contrast.

use std::sync::OnceLock;

use nalgebra::{Matrix3, SMatrix, Vector2, Vector3};
use opencv::core::{self, Mat, Point2f, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use crate::Result;
use crate::decode::{Bits, CELLS, warp_cells};

/// Pixels per cell of the rectified marker.
const CELL_PX: usize = 4;
/// Blurs tried, as the Gaussian's sigma in cells: from none to a marker
/// barely readable.
const SIGMAS: [f64; 7] = [0.0, 0.1, 0.17, 0.25, 0.35, 0.5, 0.7];
/// Side of the rectified square, pixels.
const SIDE: usize = CELLS * CELL_PX;

/// RMS distance of the marker with corners `quad` from the best blurred
/// drawing of `code` (row-major, white `true`, corner 0 top left), as a
/// fraction of its contrast: about a tenth or less for a printed marker,
/// more where the cells are not uniform. Counted from half a border cell
/// in, so that the surroundings reach it only through the blur.
pub fn misfit(image: &impl core::ToInputArray, quad: &[Point2f; 4], code: &Bits) -> Result<f64> {
    let warped = warp_cells(image, quad, CELL_PX as i32)?;
    Ok(misfit_of(warped.data_bytes()?, code))
}

/// [`misfit`] of a marker whose edges bow out by `bows` px at their middles
/// ([`crate::refine::edge_bows`]): the grid is warped so that its outer
/// edges follow the parabolas, each edge's bow fading linearly to nothing
/// at the opposite edge. Paper that is not flat bends the cells with its
/// edges; a pictogram printed flat keeps straight edges, so this is no
/// easier on it than [`misfit`].
pub fn misfit_bent(
    image: &impl core::ToInputArray,
    quad: &[Point2f; 4],
    bows: &[f64; 4],
    code: &Bits,
) -> Result<f64> {
    let unit = Vector::<Point2f>::from_iter([
        Point2f::new(0.0, 0.0),
        Point2f::new(1.0, 0.0),
        Point2f::new(1.0, 1.0),
        Point2f::new(0.0, 1.0),
    ]);
    let h = imgproc::get_perspective_transform(
        &unit,
        &Vector::<Point2f>::from_iter(*quad),
        core::DECOMP_LU,
    )?;
    let h = Matrix3::from_row_slice(h.data_typed::<f64>()?);
    let outward = crate::refine::outward_normals(&crate::refine::quad_f64(quad));
    let n = SIDE as i32;
    let mut map_x = Mat::new_rows_cols_with_default(n, n, core::CV_32FC1, core::Scalar::all(0.0))?;
    let mut map_y = map_x.clone();
    let shape = |t: f64| 4.0 * t * (1.0 - t);
    for j in 0..SIDE {
        for i in 0..SIDE {
            let (u, v) = (
                (i as f64 + 0.5) / SIDE as f64,
                (j as f64 + 0.5) / SIDE as f64,
            );
            let p = h * Vector3::new(u, v, 1.0);
            let flat = Vector2::new(p.x / p.z, p.y / p.z);
            // Edges 0 (top, along u), 1 (right, along v), 2 (bottom, u
            // backwards), 3 (left, v backwards); the parabola is symmetric.
            let bent = flat
                + outward[0] * (bows[0] * shape(u) * (1.0 - v))
                + outward[1] * (bows[1] * shape(v) * u)
                + outward[2] * (bows[2] * shape(u) * v)
                + outward[3] * (bows[3] * shape(v) * (1.0 - u));
            *map_x.at_2d_mut::<f32>(j as i32, i as i32)? = bent.x as f32;
            *map_y.at_2d_mut::<f32>(j as i32, i as i32)? = bent.y as f32;
        }
    }
    let mut warped = Mat::default();
    imgproc::remap(
        image,
        &mut warped,
        &map_x,
        &map_y,
        imgproc::INTER_LINEAR,
        core::BORDER_REPLICATE,
        core::Scalar::all(0.0),
    )?;
    Ok(misfit_of(warped.data_bytes()?, code))
}

/// [`misfit`] of the rectified square's pixels.
fn misfit_of(pixels: &[u8], code: &Bits) -> f64 {
    let white = cells(code);
    let y = Square::from_fn(|r, c| f64::from(pixels[(r + INSIDE) * SIDE + c + INSIDE]));
    let mut best = f64::INFINITY;
    for blur in blurs() {
        // The grid blurred: each cell's indicator blurs apart along rows and
        // columns, so the model is `blur * white * blur^T`. The surroundings
        // (a white margin, or whatever the marker lies on) blur in too, with
        // a brightness of their own.
        let model = blur * white * blur.transpose();
        let reach = blur.column_sum();
        let outside = Square::from_element(1.0) - reach * reach.transpose();
        best = best.min(relative_residual(&model, &outside, &y));
    }
    best
}

/// Pixels of the rectified square left out on each side: half a border cell.
const INSIDE: usize = CELL_PX / 2;
/// Rows (or columns) of the rectified square that count.
const COUNTED: usize = SIDE - 2 * INSIDE;
/// The counted pixels of the rectified square.
type Square = SMatrix<f64, COUNTED, COUNTED>;
/// For one blur: how much of each cell's row (or column) reaches each
/// counted pixel row (or column).
type Blur = SMatrix<f64, COUNTED, CELLS>;

/// The blurs of [`SIGMAS`], each a discrete Gaussian over the rectified
/// pixels. What lies beyond the square belongs to no cell: its share of a
/// pixel is what the cells leave.
fn blurs() -> &'static [Blur; SIGMAS.len()] {
    static BLURS: OnceLock<[Blur; SIGMAS.len()]> = OnceLock::new();
    BLURS.get_or_init(|| {
        SIGMAS.map(|sigma| {
            let s = sigma * CELL_PX as f64;
            let radius = (4.0 * s).ceil() as i64;
            let weights: Vec<f64> = (-radius..=radius)
                .map(|d| {
                    if s == 0.0 {
                        1.0
                    } else {
                        (-(d * d) as f64 / (2.0 * s * s)).exp()
                    }
                })
                .collect();
            let total: f64 = weights.iter().sum();
            Blur::from_fn(|row, cell| {
                let y = (row + INSIDE) as i64;
                (-radius..=radius)
                    .filter(|d| (0..SIDE as i64).contains(&(y + d)))
                    .filter(|d| (y + d) as usize / CELL_PX == cell)
                    .map(|d| weights[(d + radius) as usize])
                    .sum::<f64>()
                    / total
            })
        })
    })
}

/// RMS residual of the least-squares fit `y = a m + c o + b` (grid `m`,
/// surroundings `o`), divided by `a` (the contrast the fit finds); infinite
/// when `a` is not positive.
fn relative_residual(m: &Square, o: &Square, y: &Square) -> f64 {
    let mut normal = Matrix3::<f64>::zeros();
    let mut rhs = Vector3::<f64>::zeros();
    let mut syy = 0.0;
    for ((&m, &o), &y) in m.iter().zip(o.iter()).zip(y.iter()) {
        let x = Vector3::new(m, o, 1.0);
        normal += x * x.transpose();
        rhs += x * y;
        syy += y * y;
    }
    // Unblurred, the surroundings reach no counted pixel: a faint ridge
    // keeps their term at zero then instead of the system singular.
    normal[(1, 1)] += 1e-9 * y.len() as f64;
    let Some(p) = normal.cholesky().map(|c| c.solve(&rhs)) else {
        return f64::INFINITY;
    };
    if p[0] <= 0.0 {
        return f64::INFINITY;
    }
    // Least squares leaves y.y - p.(X^T y) unexplained.
    let residual = (syy - p.dot(&rhs)).max(0.0) / y.len() as f64;
    residual.sqrt() / p[0]
}

/// The marker's cells: 1 for a white cell, 0 for black; the border black.
fn cells(code: &Bits) -> SMatrix<f64, CELLS, CELLS> {
    SMatrix::from_fn(|r, c| {
        let inner = (1..CELLS - 1).contains(&r) && (1..CELLS - 1).contains(&c);
        if inner && code[(r - 1) * 4 + c - 1] {
            1.0
        } else {
            0.0
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Checks, CodeBook, Correction, Detector};
    use opencv::aruco;
    use opencv::core::{Point, Rect, Scalar, Size};

    /// A white page with `DICT_4X4_50` marker `id` of `side` px at `at`.
    fn page_with_marker(id: i32, side: i32, at: (i32, i32)) -> Mat {
        let dictionary =
            aruco::get_predefined_dictionary(aruco::PREDEFINED_DICTIONARY_NAME::DICT_4X4_50)
                .unwrap();
        let mut marker = Mat::default();
        aruco::draw_marker(&dictionary, id, side, &mut marker, 1).unwrap();
        let mut page =
            Mat::new_rows_cols_with_default(240, 320, core::CV_8U, Scalar::all(230.0)).unwrap();
        let mut roi = Mat::roi_mut(&mut page, Rect::new(at.0, at.1, side, side)).unwrap();
        marker.copy_to(&mut roi).unwrap();
        page
    }

    /// A fragile-glass label, 60 px: a white cup, stem and foot in a black
    /// square, drawn so that its 4x4 cells read as id 17 (a white 2x2 block
    /// at the top).
    fn draw_glass(page: &mut Mat, at: (i32, i32)) {
        let fill = |page: &mut Mat, x: i32, y: i32, w: i32, h: i32, v: f64| {
            imgproc::rectangle(
                page,
                Rect::new(at.0 + x, at.1 + y, w, h),
                Scalar::all(v),
                imgproc::FILLED,
                imgproc::LINE_8,
                0,
            )
            .unwrap();
        };
        fill(page, 0, 0, 60, 60, 20.0);
        // The cup, narrower than the two cells it lights, rounded below and
        // cracked from its rim, as the ISO 780 "fragile" symbol.
        fill(page, 22, 8, 16, 12, 230.0);
        imgproc::ellipse(
            page,
            Point::new(at.0 + 30, at.1 + 20),
            Size::new(8, 8),
            0.0,
            0.0,
            180.0,
            Scalar::all(230.0),
            imgproc::FILLED,
            imgproc::LINE_AA,
            0,
        )
        .unwrap();
        fill(page, 29, 8, 3, 9, 20.0);
        fill(page, 29, 29, 3, 12, 230.0);
        fill(page, 23, 40, 14, 3, 230.0);
    }

    fn blurred(page: &Mat, sigma: f64) -> Mat {
        if sigma == 0.0 {
            return page.clone();
        }
        let mut out = Mat::default();
        imgproc::gaussian_blur(
            page,
            &mut out,
            Size::new(0, 0),
            sigma,
            sigma,
            core::BORDER_REPLICATE,
        )
        .unwrap();
        out
    }

    fn square(at: (i32, i32), side: i32) -> [Point2f; 4] {
        let (x, y, s) = (at.0 as f32 - 0.5, at.1 as f32 - 0.5, side as f32);
        [
            Point2f::new(x, y),
            Point2f::new(x + s, y),
            Point2f::new(x + s, y + s),
            Point2f::new(x, y + s),
        ]
    }

    #[test]
    fn printed_markers_fit_their_code_a_pictogram_read_as_a_code_does_not() {
        let max = Checks::default().max_misfit;
        let book = CodeBook::new(true, Correction::None).unwrap();
        let mut worst = 0.0f64;
        let mut wrong = 0.0f64;
        for id in 0..50 {
            let code = book.code(id, false).unwrap();
            for side in [24, 48] {
                for sigma in [0.0, 1.0, 2.0] {
                    let image = blurred(&page_with_marker(id as i32, side, (40, 30)), sigma);
                    let quad = square((40, 30), side);
                    worst = worst.max(misfit(&image, &quad, &code).unwrap());
                    // The same marker against the code turned a quarter.
                    let turned: Bits = std::array::from_fn(|k| code[(3 - k % 4) * 4 + k / 4]);
                    if turned != code {
                        wrong = wrong.max(misfit(&image, &quad, &turned).unwrap());
                    }
                }
            }
        }
        eprintln!("printed markers: misfit up to {worst:.3}");
        assert!(worst < 0.1, "a printed marker's misfit {worst:.3}");
        assert!(wrong > max, "a marker against a turned code: {wrong:.3}");

        let code = book.code(17, false).unwrap();
        for sigma in [0.0, 1.0] {
            let mut page = page_with_marker(0, 60, (200, 30));
            draw_glass(&mut page, (40, 30));
            let image = blurred(&page, sigma);
            let quad = square((40, 30), 60);
            let read = book.read(&image, &quad, &Checks::default()).unwrap();
            assert_eq!(read.map(|d| d.id), Ok(17), "blur {sigma}");
            let glass = misfit(&image, &quad, &code).unwrap();
            eprintln!("glass, blur {sigma} px: misfit {glass:.3}");
            assert!(glass > max, "the glass's misfit {glass:.3}, blur {sigma}");
            // Its edges are straight: following them is no easier on it.
            let bows = crate::refine::edge_bows(&image, &quad).unwrap();
            let bent = misfit_bent(&image, &quad, &bows, &code).unwrap();
            assert!(bows.iter().all(|b| b.abs() < 0.5), "{bows:?}");
            assert!(bent > max, "the glass's misfit along its edges {bent:.3}");
        }
    }

    /// Marker `id` (300 px) on a white sheet (400 px), seen in perspective
    /// with the sheet curled: each point of the sheet `bow` px lower in the
    /// image at the marker's middle column than flat, nothing at its left
    /// and right edges. Returns the image and the marker's true corners.
    fn curled_sheet(id: i32, bow: f64) -> (Mat, [Point2f; 4]) {
        let dictionary =
            aruco::get_predefined_dictionary(aruco::PREDEFINED_DICTIONARY_NAME::DICT_4X4_50)
                .unwrap();
        let mut marker = Mat::default();
        aruco::draw_marker(&dictionary, id, 300, &mut marker, 1).unwrap();
        let mut sheet =
            Mat::new_rows_cols_with_default(400, 400, core::CV_8U, Scalar::all(255.0)).unwrap();
        marker
            .copy_to(&mut Mat::roi_mut(&mut sheet, Rect::new(50, 50, 300, 300)).unwrap())
            .unwrap();
        // The sheet's corners in the image: steeply seen, its far edge short.
        let corners = [
            (250.0, 120.0),
            (520.0, 140.0),
            (600.0, 400.0),
            (60.0, 380.0),
        ];
        let h = imgproc::get_perspective_transform(
            &Vector::<Point2f>::from_iter(
                [(0.0, 0.0), (400.0, 0.0), (400.0, 400.0), (0.0, 400.0)]
                    .map(|(x, y)| Point2f::new(x, y)),
            ),
            &Vector::<Point2f>::from_iter(corners.map(|(x, y)| Point2f::new(x, y))),
            core::DECOMP_LU,
        )
        .unwrap();
        let h = Matrix3::from_fn(|r, c| *h.at_2d::<f64>(r as i32, c as i32).unwrap());
        let inverse = h.try_inverse().unwrap();
        let flat_to_sheet = |x: f64, y: f64| {
            let p = inverse * Vector3::new(x, y, 1.0);
            (p.x / p.z, p.y / p.z)
        };
        let shift = |u: f64| {
            let t = ((u - 50.0) / 300.0).clamp(0.0, 1.0);
            bow * 4.0 * t * (1.0 - t)
        };
        let (w, h_px) = (640, 480);
        let mut map_x =
            Mat::new_rows_cols_with_default(h_px, w, core::CV_32FC1, Scalar::all(0.0)).unwrap();
        let mut map_y = map_x.clone();
        for y in 0..h_px {
            for x in 0..w {
                // The sheet point seen here: image = H(u, v) + (0, shift(u)),
                // solved by fixed-point iteration.
                let (mut u, mut v) = flat_to_sheet(f64::from(x), f64::from(y));
                for _ in 0..8 {
                    (u, v) = flat_to_sheet(f64::from(x), f64::from(y) - shift(u));
                }
                *map_x.at_2d_mut::<f32>(y, x).unwrap() = u as f32;
                *map_y.at_2d_mut::<f32>(y, x).unwrap() = v as f32;
            }
        }
        let mut image = Mat::default();
        imgproc::remap(
            &sheet,
            &mut image,
            &map_x,
            &map_y,
            imgproc::INTER_LINEAR,
            core::BORDER_CONSTANT,
            Scalar::all(120.0),
        )
        .unwrap();
        let image = blurred(&image, 1.0);
        let truth = [(50.0, 50.0), (350.0, 50.0), (350.0, 350.0), (50.0, 350.0)].map(|(u, v)| {
            let p = h * Vector3::new(u, v, 1.0);
            Point2f::new((p.x / p.z - 0.5) as f32, (p.y / p.z - 0.5) as f32)
        });
        (image, truth)
    }

    #[test]
    fn a_marker_on_curled_paper_fits_its_code_along_its_bowed_edges() {
        let book = CodeBook::new(true, Correction::None).unwrap();
        let max = Checks::default().max_misfit;
        for bow in [8.0, 14.0] {
            let (image, truth) = curled_sheet(7, bow);
            let found = Detector::new(true).unwrap().detect(&image).unwrap();
            assert_eq!(found.len(), 1, "bow {bow}: {found:?}");
            assert_eq!(found[0].id, 7);
            // The corners come from lines fitted to the edges' halves: on a
            // strongly bowed edge a half's line misses its corner by a few
            // px (6 at 14 px of bow), which is left as it is.
            for k in 0..4 {
                let (x, y) = (found[0].corners[2 * k], found[0].corners[2 * k + 1]);
                let error = (x - f64::from(truth[k].x)).hypot(y - f64::from(truth[k].y));
                assert!(
                    error < if bow < 10.0 { 1.5 } else { 8.0 },
                    "bow {bow}: corner {k} {error:.2} px from the truth"
                );
            }
            // The edges' bows measured: the top and bottom edges' by the
            // shift seen along their normals, the sides straight.
            let quad = truth;
            let bows = crate::refine::edge_bows(&image, &quad).unwrap();
            let along_normal = |a: Point2f, b: Point2f| {
                let (dx, dy) = (f64::from(b.x - a.x), f64::from(b.y - a.y));
                bow * dx.abs() / dx.hypot(dy)
            };
            let (top, bottom) = (
                along_normal(quad[0], quad[1]),
                along_normal(quad[2], quad[3]),
            );
            assert!(
                (bows[0] + top).abs() < 0.15 * top,
                "bow {bow}: {bows:?}, top {top:.2}"
            );
            assert!(
                (bows[2] - bottom).abs() < 0.15 * bottom,
                "bow {bow}: {bows:?}, bottom {bottom:.2}"
            );
            assert!(
                bows[1].abs() < 0.5 && bows[3].abs() < 0.5,
                "bow {bow}: {bows:?}"
            );
            // The flat grid misfits; the grid that follows the edges fits.
            let code = book.code(7, false).unwrap();
            let flat = misfit(&image, &quad, &code).unwrap();
            let bent = misfit_bent(&image, &quad, &bows, &code).unwrap();
            eprintln!(
                "bow {bow} px: misfit flat {flat:.3}, along the edges {bent:.3}; bows {bows:.2?}"
            );
            assert!(
                flat > max && bent < 0.1,
                "bow {bow}: flat {flat:.3}, bent {bent:.3}"
            );
        }
    }

    #[test]
    fn the_detector_reports_a_printed_marker_and_not_a_pictogram_that_reads_alike() {
        let mut page = page_with_marker(17, 60, (200, 30));
        draw_glass(&mut page, (40, 30));
        let image = blurred(&page, 1.0);
        let found = |max_misfit: f64| {
            let mut options = crate::Options::new(true);
            options.checks.max_misfit = max_misfit;
            let mut detector = Detector::with_options(options).unwrap();
            detector.detect(&image).unwrap()
        };
        let ours = found(Checks::default().max_misfit);
        assert_eq!(ours.len(), 1, "{ours:?}");
        assert_eq!(ours[0].id, 17);
        assert!(
            (ours[0].center[0] - 229.5).abs() < 0.5,
            "{:?}",
            ours[0].center
        );
        // Without the check the pictogram is reported too.
        let unchecked = found(f64::INFINITY);
        assert_eq!(unchecked.len(), 2, "{unchecked:?}");
    }
}
