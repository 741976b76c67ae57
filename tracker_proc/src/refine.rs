//! Sub-pixel corners from the marker's four outer edges.
//!
//! OpenCV's `cornerSubPix` looks at a fixed window around each corner; on a
//! small marker next to a label or another marker that window reaches the
//! neighbour's edges and the corner is pulled onto them. Here each outer
//! edge is located over its whole length instead: in every pixel column (or
//! row) that crosses it, the edge is where the part of the brightness
//! gradient that points outward (dark border inside, light surround
//! outside) peaks, to a sub-pixel by a parabola through the peak; the line
//! is the weighted total-least-squares fit of those points, and the corners
//! are where adjacent lines meet. Gradients of the other sense (a label's
//! edge beyond the white margin, the inner edge of the border) never peak.
//! A long edge, which lens distortion bends, is fitted by halves, each
//! corner from the halves that meet there; the first look reaches up to
//! 8 px from the candidate's edge, as far as a blurred corner's polygon may
//! be off. A peak is where the edge is wherever the look was centred, so
//! the corners do not depend on which candidate polygon they started from
//! (a full scan's or a window's, at any threshold scale).

use nalgebra::{Matrix2, Vector2};
use opencv::core::Point2f;
use opencv::prelude::*;

/// Share of each edge left out at both ends (the corners' rounding and the
/// neighbouring edge's gradient).
const END_MARGIN: f64 = 0.15;

/// Edges longer than this are fitted by halves, px.
const SPLIT_EDGES_OVER_PX: f64 = 80.0;
/// Narrow looks about the last fit.
const NARROW_PASSES: usize = 2;

/// A line `normal . p = offset`, `normal` of unit length.
#[derive(Debug, Clone, Copy, Default)]
struct Line {
    normal: Vector2<f64>,
    offset: f64,
}

impl Line {
    fn intersect(&self, other: &Line) -> Option<Vector2<f64>> {
        Matrix2::from_rows(&[self.normal.transpose(), other.normal.transpose()])
            .try_inverse()
            .map(|m| m * Vector2::new(self.offset, other.offset))
    }
}

/// The pixels around a marker, copied once out of the image (a `Mat` read
/// pixel by pixel costs a bounds-checked call each), with the image's
/// borders clamped.
struct Patch {
    x0: i32,
    y0: i32,
    width: i32,
    height: i32,
    /// Image size, for the border test.
    image_width: i32,
    image_height: i32,
    pixels: Vec<u8>,
}

impl Patch {
    /// The pixels within `reach` of the box spanned by `points`.
    fn around(image: &impl MatTraitConst, points: &[Vector2<f64>], reach: f64) -> Option<Self> {
        let (image_width, image_height) = (image.cols(), image.rows());
        let lo = points
            .iter()
            .fold(Vector2::repeat(f64::MAX), |a, p| a.inf(p));
        let hi = points
            .iter()
            .fold(Vector2::repeat(f64::MIN), |a, p| a.sup(p));
        let x0 = ((lo.x - reach).floor() as i32).clamp(0, image_width - 1);
        let y0 = ((lo.y - reach).floor() as i32).clamp(0, image_height - 1);
        let x1 = ((hi.x + reach).ceil() as i32).clamp(0, image_width - 1);
        let y1 = ((hi.y + reach).ceil() as i32).clamp(0, image_height - 1);
        let (width, height) = (x1 - x0 + 1, y1 - y0 + 1);
        let mut pixels = Vec::with_capacity((width * height) as usize);
        for y in y0..=y1 {
            let row = image.at_row::<u8>(y).ok()?;
            pixels.extend_from_slice(row.get(x0 as usize..=x1 as usize)?);
        }
        Some(Self {
            x0,
            y0,
            width,
            height,
            image_width,
            image_height,
            pixels,
        })
    }

    fn at(&self, x: i32, y: i32) -> f64 {
        let x = (x - self.x0).clamp(0, self.width - 1);
        let y = (y - self.y0).clamp(0, self.height - 1);
        f64::from(self.pixels[(y * self.width + x) as usize])
    }

    /// Whether the Sobel window at (x, y) lies inside the image.
    fn interior(&self, x: i32, y: i32) -> bool {
        x >= 1 && y >= 1 && x < self.image_width - 1 && y < self.image_height - 1
    }

    /// Sobel gradient at a pixel, grey levels per pixel.
    fn gradient(&self, x: i32, y: i32) -> Vector2<f64> {
        let p = |dx: i32, dy: i32| self.at(x + dx, y + dy);
        let gx = (p(1, -1) + 2.0 * p(1, 0) + p(1, 1) - p(-1, -1) - 2.0 * p(-1, 0) - p(-1, 1)) / 8.0;
        let gy = (p(-1, 1) + 2.0 * p(0, 1) + p(1, 1) - p(-1, -1) - 2.0 * p(0, -1) - p(1, -1)) / 8.0;
        Vector2::new(gx, gy)
    }
}

/// An edge: points on it, each weighted by the square of its outward
/// gradient.
struct Band {
    points: Vec<(Vector2<f64>, f64)>,
    /// The direction in which brightness rises across the edge.
    outward: Vector2<f64>,
}

impl Band {
    /// Where the edge from `a` to `b` crosses each pixel column (or row,
    /// for an edge steeper than 45 degrees) between `END_MARGIN` and
    /// `1 - END_MARGIN` of its length: the sub-pixel peak of the outward
    /// gradient (brightness rising outward) among the pixels within
    /// `half_width` of `line`. A peak at the end of its run lies beyond the
    /// band and is left out. Each point is where the edge is, wherever in
    /// the band the look was centred: the fit does not depend on its start.
    fn collect(
        grey: &Patch,
        (a, b): (Vector2<f64>, Vector2<f64>),
        span: (f64, f64),
        line: Line,
        half_width: f64,
    ) -> Option<Self> {
        let outward = line.normal;
        let length = (b - a).norm();
        let along = (b - a) / length;
        // Scan across the edge along the axis nearer its normal.
        let steep = line.normal.x.abs() > line.normal.y.abs();
        let (n_scan, n_across) = if steep {
            (line.normal.y, line.normal.x)
        } else {
            (line.normal.x, line.normal.y)
        };
        let to_xy = |s: i32, u: i32| if steep { (u, s) } else { (s, u) };
        let point = |s: f64, u: f64| {
            if steep {
                Vector2::new(u, s)
            } else {
                Vector2::new(s, u)
            }
        };
        let (s_lo, s_hi) = if steep {
            (a.y.min(b.y), a.y.max(b.y))
        } else {
            (a.x.min(b.x), a.x.max(b.x))
        };
        // A long edge has columns to spare: every even one halves the work
        // (the same ones whatever the start).
        let stride = if length > 60.0 { 2 } else { 1 };
        let first = if stride == 2 {
            s_lo.floor() as i32 & !1
        } else {
            s_lo.floor() as i32
        };
        let reach = half_width / n_across.abs();
        let mut points = Vec::new();
        let mut run: Vec<f64> = Vec::new();
        for s in (first..=s_hi.ceil() as i32).step_by(stride) {
            // The line's crossing of this column, across the edge.
            let centre = (line.offset - n_scan * f64::from(s)) / n_across;
            let t = (point(f64::from(s), centre) - a).dot(&along) / length;
            if !(span.0..=span.1).contains(&t) {
                continue;
            }
            let (u0, u1) = (
                (centre - reach).ceil() as i32,
                (centre + reach).floor() as i32,
            );
            run.clear();
            for u in u0..=u1 {
                let (x, y) = to_xy(s, u);
                run.push(if grey.interior(x, y) {
                    grey.gradient(x, y).dot(&outward)
                } else {
                    f64::NAN
                });
            }
            // NaN (outside the image) never wins; a peak at either end of
            // the run, or not rising outward, is not this edge's.
            let Some(k) = (0..run.len())
                .filter(|&k| run[k] > 0.0)
                .max_by(|&i, &j| run[i].total_cmp(&run[j]))
            else {
                continue;
            };
            if k == 0 || k + 1 == run.len() || run[k - 1].is_nan() || run[k + 1].is_nan() {
                continue;
            }
            let (g0, g1, g2) = (run[k - 1], run[k], run[k + 1]);
            let curvature = g0 - 2.0 * g1 + g2;
            let delta = if curvature < 0.0 {
                (0.5 * (g0 - g2) / curvature).clamp(-0.5, 0.5)
            } else {
                0.0
            };
            let u = f64::from(u0 + k as i32) + delta;
            points.push((point(f64::from(s), u), g1 * g1));
        }
        (points.len() >= 3).then_some(Self { points, outward })
    }

    /// The weighted total-least-squares line, its normal pointing outward.
    fn line(&self) -> Option<Line> {
        let sum_w: f64 = self.points.iter().map(|(_, w)| w).sum();
        if sum_w <= 0.0 {
            return None;
        }
        let mean = self
            .points
            .iter()
            .map(|(p, w)| *w * p)
            .sum::<Vector2<f64>>()
            / sum_w;
        let mut cov = Matrix2::zeros();
        for (p, w) in &self.points {
            let d = p - mean;
            cov += *w * d * d.transpose();
        }
        let eig = cov.symmetric_eigen();
        let k = usize::from(eig.eigenvalues[0] >= eig.eigenvalues[1]);
        let mut normal = eig.eigenvectors.column(k).into_owned();
        if normal.dot(&self.outward) < 0.0 {
            normal = -normal;
        }
        Some(Line {
            normal,
            offset: normal.dot(&mean),
        })
    }
}

/// The corners of a marker located from its four edges; `None` when an edge
/// gives no line or the corners would move implausibly far (more than a
/// fifth of the shortest side).
pub fn refine_corners(image: &impl MatTraitConst, corners: &[Point2f; 4]) -> Option<[Point2f; 4]> {
    let c = quad_f64(corners);
    let shortest = (0..4)
        .map(|k| (c[(k + 1) % 4] - c[k]).norm())
        .fold(f64::INFINITY, f64::min);
    // A long edge, which the lens bends, is fitted by halves.
    let halves = shortest > SPLIT_EDGES_OVER_PX;
    // A wide look about the candidate's edges (its corners are whole
    // pixels, and on a blurred marker its polygon lies inside the edges by
    // up to a twentieth of its side), then narrow ones about the last fits,
    // each over the edges between the last fit's corners: what the corners
    // settle on does not depend on the candidate's polygon.
    let wide = (0.12 * shortest).max(2.5);
    let narrow = (0.5 * wide).max(2.0);
    // The narrow looks' reach beyond an edge that a wide look moved, plus
    // the Sobel window.
    let grey = Patch::around(image, &c, wide + narrow + 3.0)?;
    let mut lines = edge_lines(&grey, &c, None, halves, wide)?;
    for _ in 0..NARROW_PASSES {
        let fitted = corners_of(&lines)?;
        lines = edge_lines(&grey, &fitted, Some(&lines), halves, narrow)?;
    }
    let fitted = corners_of(&lines)?;
    let mut out = [Point2f::default(); 4];
    for k in 0..4 {
        if (fitted[k] - c[k]).norm() > 0.2 * shortest {
            return None;
        }
        out[k] = Point2f::new(fitted[k].x as f32, fitted[k].y as f32);
    }
    Some(out)
}

/// How far each edge of a marker bows out at its middle from the straight
/// line between its corners, px (outward positive; edge k runs from corner
/// k to corner k + 1): the parabola through both corners fitted to the
/// edge's points. A marker printed on paper that is not flat, or on a
/// curved face, bows; a flat one gives a fraction of a pixel. `None` when
/// an edge gives too few points.
pub fn edge_bows(image: &impl MatTraitConst, corners: &[Point2f; 4]) -> Option<[f64; 4]> {
    let c = quad_f64(corners);
    let shortest = (0..4)
        .map(|k| (c[(k + 1) % 4] - c[k]).norm())
        .fold(f64::INFINITY, f64::min);
    let half_width = (0.12 * shortest).max(2.5);
    let grey = Patch::around(image, &c, half_width + 3.0)?;
    let normals = outward_normals(&c);
    let mut bows = [0.0; 4];
    for (k, bow) in bows.iter_mut().enumerate() {
        let (a, b) = (c[k], c[(k + 1) % 4]);
        let length = (b - a).norm();
        let along = (b - a) / length;
        let outward = normals[k];
        let chord = Line {
            normal: outward,
            offset: outward.dot(&a),
        };
        let band = Band::collect(
            &grey,
            (a, b),
            (END_MARGIN, 1.0 - END_MARGIN),
            chord,
            half_width,
        )?;
        // Weighted least squares of d = bow * 4t(1 - t).
        let (mut num, mut den) = (0.0, 0.0);
        for (p, w) in &band.points {
            let t = (p - a).dot(&along) / length;
            let shape = 4.0 * t * (1.0 - t);
            num += w * shape * (outward.dot(p) - chord.offset);
            den += w * shape * shape;
        }
        if den <= 0.0 {
            return None;
        }
        *bow = num / den;
    }
    Some(bows)
}

/// Per edge of the quadrilateral `c`, the line near its start and the line
/// near its end (the same line, or with `halves` one over each half),
/// fitted to the edge points within `half_width` of the lines `about` (of
/// the edge itself when there are none).
fn edge_lines(
    grey: &Patch,
    c: &[Vector2<f64>; 4],
    about: Option<&[(Line, Line); 4]>,
    halves: bool,
    half_width: f64,
) -> Option<[(Line, Line); 4]> {
    let normals = outward_normals(c);
    let mut lines = [(Line::default(), Line::default()); 4];
    for k in 0..4 {
        let (a, b) = (c[k], c[(k + 1) % 4]);
        let outward = normals[k];
        let edge = Line {
            normal: outward,
            offset: outward.dot(&a),
        };
        let (first, second) = about.map_or((edge, edge), |l| l[k]);
        let fit = |span: (f64, f64), about: Line| -> Option<Line> {
            Band::collect(grey, (a, b), span, about, half_width)?.line()
        };
        lines[k] = if halves {
            (
                fit((END_MARGIN, 0.5), first)?,
                fit((0.5, 1.0 - END_MARGIN), second)?,
            )
        } else {
            let line = fit((END_MARGIN, 1.0 - END_MARGIN), first)?;
            (line, line)
        };
    }
    Some(lines)
}

/// A quadrilateral's corners in double precision.
pub(crate) fn quad_f64(corners: &[Point2f; 4]) -> [Vector2<f64>; 4] {
    corners.map(|p| Vector2::new(f64::from(p.x), f64::from(p.y)))
}

/// The unit normal of each edge of the quadrilateral `c` (edge k from
/// corner k to corner k + 1), pointing away from its centre.
pub(crate) fn outward_normals(c: &[Vector2<f64>; 4]) -> [Vector2<f64>; 4] {
    let center = c.iter().sum::<Vector2<f64>>() / 4.0;
    std::array::from_fn(|k| {
        let (a, b) = (c[k], c[(k + 1) % 4]);
        let along = (b - a).normalize();
        let n = Vector2::new(along.y, -along.x);
        if n.dot(&((a + b) / 2.0 - center)) < 0.0 {
            -n
        } else {
            n
        }
    })
}

/// Where adjacent edges' lines meet: corner k ends edge k - 1 and starts
/// edge k.
fn corners_of(lines: &[(Line, Line); 4]) -> Option<[Vector2<f64>; 4]> {
    let mut corners = [Vector2::zeros(); 4];
    for (k, corner) in corners.iter_mut().enumerate() {
        *corner = lines[(k + 3) % 4].1.intersect(&lines[k].0)?;
    }
    Some(corners)
}

#[cfg(test)]
mod tests {
    use super::*;
    use opencv::core::{self, Mat, Point, Scalar, Size, Vector};
    use opencv::imgproc;

    /// A dark square on a light field, blurred (sigma 1.4 px, as the
    /// realistic look's defocus), drawn 8 times larger and shrunk by area
    /// averaging so its edges are placed to a fraction of a pixel; and its
    /// true corners.
    fn blurred_square() -> (Mat, [Vector2<f64>; 4]) {
        let (centre, half, angle) = (Vector2::new(50.3, 49.6), 17.0, 0.3f64);
        let corners = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(u, v)| {
            let (s, c) = angle.sin_cos();
            centre + half * Vector2::new(c * u - s * v, s * u + c * v)
        });
        let scale = 8.0;
        let mut big =
            Mat::new_rows_cols_with_default(800, 800, core::CV_8UC1, Scalar::all(200.0)).unwrap();
        let poly: Vector<Point> = corners
            .iter()
            .map(|p| {
                let q = (p.add_scalar(0.5)) * scale - Vector2::repeat(0.5);
                Point::new(q.x.round() as i32, q.y.round() as i32)
            })
            .collect();
        imgproc::fill_convex_poly(&mut big, &poly, Scalar::all(30.0), imgproc::LINE_8, 0).unwrap();
        let mut small = Mat::default();
        imgproc::resize(
            &big,
            &mut small,
            Size::new(100, 100),
            0.0,
            0.0,
            imgproc::INTER_AREA,
        )
        .unwrap();
        let mut blurred = Mat::default();
        imgproc::gaussian_blur(
            &small,
            &mut blurred,
            Size::new(0, 0),
            1.4,
            0.0,
            core::BORDER_REPLICATE,
        )
        .unwrap();
        (blurred, corners)
    }

    /// From candidate polygons a pixel or two off in different ways (as a
    /// full scan's and a window's thresholds give), the fitted corners are
    /// the same and on the true ones (within 0.15 px: the filled polygon
    /// takes in its boundary's pixels, half of one of the 8-times image
    /// outward on each side, and the fits land 0.06-0.12 px outward).
    #[test]
    fn corners_do_not_depend_on_the_polygon_they_start_from() {
        let (image, truth) = blurred_square();
        let starts: [[(f64, f64); 4]; 4] = [
            [(0.0, 0.0); 4],
            [(1.0, -1.0), (-1.0, 0.0), (0.0, 1.0), (1.0, 1.0)],
            [(-2.0, 1.0), (1.0, 2.0), (2.0, -1.0), (-1.0, -2.0)],
            [(0.5, 1.5), (1.5, 0.5), (-1.5, 0.5), (0.5, -1.5)],
        ];
        let fits: Vec<[Point2f; 4]> = starts
            .iter()
            .map(|offsets| {
                let start: [Point2f; 4] = std::array::from_fn(|k| {
                    let p = truth[k] + Vector2::new(offsets[k].0, offsets[k].1);
                    Point2f::new(p.x.round() as f32, p.y.round() as f32)
                });
                refine_corners(&image, &start).expect("a fit")
            })
            .collect();
        for fit in &fits {
            for k in 0..4 {
                let (p, q) = (fit[k], fits[0][k]);
                let apart = f64::from((p.x - q.x).hypot(p.y - q.y));
                assert!(
                    apart < 0.01,
                    "corner {k}: {apart:.4} px from the first start's"
                );
                let off = (Vector2::new(f64::from(p.x), f64::from(p.y)) - truth[k]).norm();
                assert!(off < 0.15, "corner {k}: {off:.3} px from the truth");
            }
        }
    }
}
