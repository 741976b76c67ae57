//! Sub-pixel corners from the marker's four outer edges.
//!
//! OpenCV's `cornerSubPix` looks at a fixed window around each corner; on a
//! small marker next to a label or another marker that window reaches the
//! neighbour's edges and the corner is pulled onto them. Here each outer
//! edge is located over its whole length instead: every pixel in a thin band
//! along the edge votes with the part of its brightness gradient that
//! points outward (dark border inside, light surround outside), the line is
//! the weighted total-least-squares fit of those pixels, and the corners are
//! where adjacent lines meet. Gradients of the other sense (a label's edge
//! beyond the white margin, the inner edge of the border) get no vote. A
//! long edge, which lens distortion bends, is fitted by halves, each corner
//! from the halves that meet there; the first look reaches up to 8 px from
//! the candidate's edge, as far as a blurred corner's polygon may be off.

use nalgebra::{Matrix2, Vector2};
use opencv::core::Point2f;
use opencv::prelude::*;

/// Share of each edge left out at both ends (the corners' rounding and the
/// neighbouring edge's gradient).
const END_MARGIN: f64 = 0.15;

/// How far beyond a candidate's edge the first look reaches, px.
const MAX_WIDE: f64 = 8.0;
/// Edges longer than this are fitted by halves, px.
const SPLIT_EDGES_OVER_PX: f64 = 80.0;
/// Narrow looks about the last fit.
const NARROW_PASSES: usize = 2;

/// A line `normal . p = offset`, `normal` of unit length.
#[derive(Debug, Clone, Copy)]
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

/// An edge: pixels in a band along a-b, each weighted by the square of its
/// outward gradient.
struct Band {
    points: Vec<(Vector2<f64>, f64)>,
}

impl Band {
    /// The pixels between `END_MARGIN` and `1 - END_MARGIN` along the edge
    /// from `a` to `b` that lie within `half_width` of `line` and whose
    /// brightness rises outward.
    fn collect(
        grey: &Patch,
        (a, b): (Vector2<f64>, Vector2<f64>),
        span: (f64, f64),
        outward: Vector2<f64>,
        line: Line,
        half_width: f64,
    ) -> Option<Self> {
        let length = (b - a).norm();
        let along = (b - a) / length;
        let (lo, hi) = (
            a.zip_map(&b, f64::min).add_scalar(-half_width - 1.0),
            a.zip_map(&b, f64::max).add_scalar(half_width + 1.0),
        );
        // A long edge has pixels to spare: every other one (a checkerboard)
        // halves the work without favouring either side.
        let sparse = length > 60.0;
        let mut points = Vec::new();
        for y in lo.y.floor() as i32..=hi.y.ceil() as i32 {
            for x in lo.x.floor() as i32..=hi.x.ceil() as i32 {
                if (sparse && (x + y) % 2 != 0) || !grey.interior(x, y) {
                    continue;
                }
                let p = Vector2::new(f64::from(x), f64::from(y));
                let t = (p - a).dot(&along) / length;
                if !(span.0..=span.1).contains(&t) {
                    continue;
                }
                if (line.normal.dot(&p) - line.offset).abs() > half_width {
                    continue;
                }
                let outward_gradient = grey.gradient(x, y).dot(&outward);
                if outward_gradient > 0.0 {
                    points.push((p, outward_gradient * outward_gradient));
                }
            }
        }
        (points.len() >= 4).then_some(Self { points })
    }

    /// The weighted total-least-squares line, its normal pointing outward.
    fn line(&self, outward: Vector2<f64>) -> Option<Line> {
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
        if normal.dot(&outward) < 0.0 {
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
    let c: Vec<Vector2<f64>> = corners
        .iter()
        .map(|p| Vector2::new(f64::from(p.x), f64::from(p.y)))
        .collect();
    // The widest look is MAX_WIDE px beyond an edge, plus the Sobel window.
    let grey = Patch::around(image, &c, MAX_WIDE + 3.0)?;
    let center = c.iter().sum::<Vector2<f64>>() / 4.0;
    let shortest = (0..4)
        .map(|k| (c[(k + 1) % 4] - c[k]).norm())
        .fold(f64::INFINITY, f64::min);
    // Per edge, the line near its start and the line near its end: one
    // line over the whole edge, or on a long edge (which the lens bends) a
    // line over each half.
    let halves = shortest > SPLIT_EDGES_OVER_PX;
    let mut lines = Vec::with_capacity(4);
    for k in 0..4 {
        let (a, b) = (c[k], c[(k + 1) % 4]);
        let along = (b - a).normalize();
        let mut outward = Vector2::new(along.y, -along.x);
        if outward.dot(&((a + b) / 2.0 - center)) < 0.0 {
            outward = -outward;
        }
        let start = Line {
            normal: outward,
            offset: outward.dot(&a),
        };
        let fit = |span: (f64, f64)| -> Option<Line> {
            // A wide look first (the candidate's corners are whole pixels),
            // then narrow ones about the last fit.
            let wide = (0.12 * shortest).clamp(1.5, MAX_WIDE);
            let mut line =
                Band::collect(&grey, (a, b), span, outward, start, wide)?.line(outward)?;
            let narrow = (0.5 * wide).max(1.2);
            for _ in 0..NARROW_PASSES {
                line = Band::collect(&grey, (a, b), span, outward, line, narrow)?.line(outward)?;
            }
            Some(line)
        };
        if halves {
            lines.push((fit((END_MARGIN, 0.5))?, fit((0.5, 1.0 - END_MARGIN))?));
        } else {
            let line = fit((END_MARGIN, 1.0 - END_MARGIN))?;
            lines.push((line, line));
        }
    }
    let mut out = [Point2f::default(); 4];
    for k in 0..4 {
        // Corner k ends edge k - 1 and starts edge k.
        let p = lines[(k + 3) % 4].1.intersect(&lines[k].0)?;
        if (p - c[k]).norm() > 0.2 * shortest {
            return None;
        }
        out[k] = Point2f::new(p.x as f32, p.y as f32);
    }
    Some(out)
}
