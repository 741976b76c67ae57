//! The borders of a binary image, as OpenCV's `findContours` with
//! `RETR_LIST` and `CHAIN_APPROX_NONE` finds them (Suzuki and Abe's border
//! following, as OpenCV 4.6 implements it in `cvFindNextContour` and
//! `icvFetchContour`), point for point and in the same order.
//!
//! Why not OpenCV's own: a full scan's candidate search finds about 4000
//! borders per threshold scale in a realistic 640x480 frame, nearly all of
//! them specks of one to four pixels, and OpenCV builds a sequence for
//! each, then a vector, then our bindings copy each again. Here one working
//! image and one point buffer are reused, and only the borders whose length
//! the caller asks for are handed on; a test checks every border against
//! OpenCV's on rendered frames and real photographs.

use opencv::core::Point;

/// Steps to the 8 neighbours, counter-clockwise from the right (OpenCV's
/// chain codes 0-7), as (dx, dy).
const STEPS: [(i32, i32); 8] = [
    (1, 0),
    (1, -1),
    (0, -1),
    (-1, -1),
    (-1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

/// A traced pixel's mark, as OpenCV's (`schar` 2 and `2 | -128`):
/// `VISITED` on a border, `RIGHT_BOUND` where the border leaves it with the
/// background to its right (no hole starts after it).
const VISITED: u8 = 2;
const RIGHT_BOUND: u8 = 0x82;

/// Whether a pixel is foreground and not a right bound: OpenCV's `prev >= 1`
/// on its signed marks.
fn may_start_hole(v: u8) -> bool {
    (v as i8) >= 1
}

/// Finds the borders of binary images; keeps its buffers between images.
#[derive(Debug, Default)]
pub struct BorderScanner {
    /// The image as 0 and 1, framed by a row and column of zeros, marked as
    /// borders are traced.
    work: Vec<u8>,
    /// The width and height `work` is framed for.
    framed: (usize, usize),
    /// The border being traced, in image pixels.
    points: Vec<Point>,
    /// The borders handed on, in the order they start: where each begins
    /// in `kept_points`, and its length.
    kept: Vec<(usize, usize)>,
    kept_points: Vec<Point>,
}

impl BorderScanner {
    /// A scanner with empty buffers.
    pub fn new() -> Self {
        Self::default()
    }

    /// Finds every border (outer and hole) of `binary` (`height` rows of
    /// `width` bytes, `stride` apart; non-zero is foreground) and hands each
    /// whose length in points lies within `lengths` to `visit`, in the
    /// order `findContours` lists them (the reverse of the raster order in
    /// which they start).
    ///
    /// # Panics
    ///
    /// If `binary` is shorter than `height` rows of `stride` bytes, or
    /// `stride < width`.
    pub fn scan(
        &mut self,
        binary: &[u8],
        width: usize,
        height: usize,
        stride: usize,
        lengths: std::ops::RangeInclusive<usize>,
        visit: impl FnMut(&[Point]),
    ) {
        assert!(stride >= width && binary.len() >= stride * height.saturating_sub(1) + width);
        let (work, offset, step) = self.frame(width, height);
        for y in 0..height {
            let row = &binary[y * stride..y * stride + width];
            let out = &mut work[offset + y * step..offset + y * step + width];
            for (o, &b) in out.iter_mut().zip(row) {
                *o = u8::from(b != 0);
            }
        }
        self.scan_framed(width, height, lengths, visit);
    }

    /// The working image for a `width` x `height` binary image: the
    /// buffer, where its first pixel lies, and the bytes per row. Fill every
    /// pixel with 0 or 1, then [`BorderScanner::scan_framed`]; the frame
    /// around them is zero (tracing marks foreground pixels only, so a
    /// buffer framed for the same width and height is reused as it is; one
    /// of the same size but another shape would have pixels in its frame).
    pub fn frame(&mut self, width: usize, height: usize) -> (&mut [u8], usize, usize) {
        let step = width + 2;
        if self.framed != (width, height) || self.work.len() != step * (height + 2) {
            self.framed = (width, height);
            self.work.clear();
            self.work.resize(step * (height + 2), 0);
        }
        (&mut self.work, step + 1, step)
    }

    /// [`BorderScanner::scan`] of the image put into the working image
    /// ([`BorderScanner::frame`]).
    ///
    /// # Panics
    ///
    /// If the working image is not framed for `width` x `height`.
    pub fn scan_framed(
        &mut self,
        width: usize,
        height: usize,
        lengths: std::ops::RangeInclusive<usize>,
        mut visit: impl FnMut(&[Point]),
    ) {
        let step = width + 2;
        assert_eq!(
            self.framed,
            (width, height),
            "the working image's width and height"
        );
        // Borders in the order they start; `findContours` lists them last first.
        self.kept.clear();
        self.kept_points.clear();
        for y in 1..=height {
            let row = y * step;
            let mut prev: u8 = 0;
            let mut x = 1;
            while x <= width {
                // Skip what equals `prev`, eight pixels at a time.
                let same = u64::from(prev) * 0x0101_0101_0101_0101;
                while x + 8 <= width + 1
                    && u64::from_ne_bytes(
                        self.work[row + x..row + x + 8].try_into().expect("8 bytes"),
                    ) == same
                {
                    x += 8;
                }
                while x <= width && self.work[row + x] == prev {
                    x += 1;
                }
                if x > width {
                    break;
                }
                let p = self.work[row + x];
                let outer = prev == 0 && p == 1;
                let hole = !outer && p == 0 && may_start_hole(prev);
                if outer || hole {
                    let origin = row + x - usize::from(hole);
                    self.trace(origin, step, hole);
                    if lengths.contains(&self.points.len()) {
                        self.kept.push((self.kept_points.len(), self.points.len()));
                        self.kept_points.extend_from_slice(&self.points);
                    }
                    // The scan goes on from the next pixel, against the
                    // start pixel as the trace left it.
                    prev = self.work[row + x];
                } else {
                    prev = p;
                }
                x += 1;
            }
        }
        for &(start, len) in self.kept.iter().rev() {
            visit(&self.kept_points[start..start + len]);
        }
    }

    /// Follows the border that starts at `origin` (an index into the work
    /// image, `step` bytes a row), marking it; its points go to `points`.
    fn trace(&mut self, origin: usize, step: usize, hole: bool) {
        let w = step as isize;
        let deltas: [isize; 8] = [1, -w + 1, -w, -w - 1, -1, w - 1, w, w + 1];
        let at = |i: usize| Point::new((i % step) as i32 - 1, (i / step) as i32 - 1);
        let image = &mut self.work;
        let points = &mut self.points;
        points.clear();
        let mut pt = at(origin);
        let i0 = origin as isize;
        let s_end = if hole { 0 } else { 4 };
        let mut s: usize = s_end;
        let mut i1;
        loop {
            s = (s + 7) & 7;
            i1 = i0 + deltas[s];
            if image[i1 as usize] != 0 || s == s_end {
                break;
            }
        }
        if s == s_end && image[i1 as usize] == 0 {
            // A single pixel.
            image[origin] = RIGHT_BOUND;
            points.push(pt);
            return;
        }
        let mut i3 = i0;
        loop {
            let s_end = s;
            // The next border pixel: the first non-zero neighbour turning
            // counter-clockwise from the one before.
            let mut i4 = i3;
            let mut k = s;
            while k < 15 {
                k += 1;
                i4 = i3 + deltas[k & 7];
                if image[i4 as usize] != 0 {
                    break;
                }
            }
            s = k & 7;
            if s.wrapping_sub(1) < s_end {
                image[i3 as usize] = RIGHT_BOUND;
            } else if image[i3 as usize] == 1 {
                image[i3 as usize] = VISITED;
            }
            points.push(pt);
            pt.x += STEPS[s].0;
            pt.y += STEPS[s].1;
            if i4 == i0 && i3 == i1 {
                break;
            }
            i3 = i4;
            s = (s + 4) & 7;
        }
    }
}
