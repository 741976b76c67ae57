//! OpenCV's adaptive threshold (`ADAPTIVE_THRESH_MEAN_C`,
//! `THRESH_BINARY_INV`), bit for bit, for several window sizes from one
//! integral image: a pixel is foreground where it is at least `C` darker
//! than the mean of the window around it (the image's edge pixels
//! repeated beyond it, `BORDER_REPLICATE`). OpenCV filters the image
//! afresh for each size; the candidate search thresholds at three.
//!
//! The mean is rounded as OpenCV's box filter rounds it: for windows of up
//! to 256 pixels its 16-bit sums are divided in fixed point, `(s + delta) *
//! scale >> 23`, which is not always the nearest integer; larger windows
//! round `s / n` to the nearest (never a tie: `n` is odd). A test checks the
//! result against `adaptiveThreshold` on renders and photographs.

/// The integral image of one grey image, padded by its edge pixels.
#[derive(Debug, Default)]
pub struct MeanThreshold {
    /// Sums over the padded image's top-left rectangles, `(pad_w + 1)` a row.
    integral: Vec<u32>,
    pad: usize,
    width: usize,
    height: usize,
    /// Bytes between the image's rows.
    stride: usize,
    /// One row of the padded image, as the integral is summed.
    padded_row: Vec<u8>,
}

impl MeanThreshold {
    /// An empty one.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes `grey` (`height` rows of `width` bytes, `stride` apart), ready
    /// for windows of up to `largest` pixels a side.
    ///
    /// # Panics
    ///
    /// If the image is empty or `grey` is shorter than it says.
    pub fn prepare(
        &mut self,
        grey: &[u8],
        width: usize,
        height: usize,
        stride: usize,
        largest: usize,
    ) {
        assert!(width > 0 && height > 0 && stride >= width);
        assert!(grey.len() >= stride * (height - 1) + width);
        let pad = largest / 2;
        let (pw, ph) = (width + 2 * pad, height + 2 * pad);
        let iw = pw + 1;
        self.integral.clear();
        self.integral.resize(iw * (ph + 1), 0);
        let padded_row = &mut self.padded_row;
        padded_row.clear();
        padded_row.resize(pw, 0);
        for y in 0..ph {
            let sy = y.saturating_sub(pad).min(height - 1);
            let row = &grey[sy * stride..sy * stride + width];
            padded_row[..pad].fill(row[0]);
            padded_row[pad..pad + width].copy_from_slice(row);
            padded_row[pad + width..].fill(row[width - 1]);
            let (above, below) = self.integral.split_at_mut((y + 1) * iw);
            let above = &above[y * iw..];
            let below = &mut below[..iw];
            let mut run = 0u32;
            below[0] = 0;
            for x in 0..pw {
                run += u32::from(padded_row[x]);
                below[x + 1] = above[x + 1] + run;
            }
        }
        self.pad = pad;
        self.width = width;
        self.height = height;
        self.stride = stride;
    }

    /// Writes the thresholded image for a `window` (odd, 3 to
    /// [`MAX_WINDOW`], at most the `largest` prepared for) and constant `c` into `out`: 1 for
    /// foreground, 0 for background, row `y` at `out[offset + y * step..]`.
    /// `grey` is the image given to [`MeanThreshold::prepare`].
    ///
    /// # Panics
    ///
    /// If the window is even, under 3 or over the prepared size, or `out`
    /// is too short.
    pub fn binary_inv(
        &self,
        grey: &[u8],
        window: usize,
        c: f64,
        out: &mut [u8],
        offset: usize,
        step: usize,
    ) {
        assert!(window % 2 == 1 && (3..=MAX_WINDOW).contains(&window) && window / 2 <= self.pad);
        assert!(out.len() >= offset + step * (self.height - 1) + self.width);
        let n = (window * window) as u32;
        // As OpenCV's `THRESH_BINARY_INV`: foreground where
        // `src - mean <= -floor(c)`.
        let delta = c.floor() as i32;
        match Mean::new(n) {
            Mean::FixedPoint { delta: d, scale } => {
                self.rows(grey, window, out, offset, step, |s, v| {
                    (((s + d) * scale) >> SHIFT) as i32 >= i32::from(v) + delta
                })
            }
            // round(s / n) >= k, for a whole k, where s / n >= k - 1/2
            // (never equal: n is odd): 2s >= n (2k - 1).
            Mean::Nearest => {
                let n = n as i32;
                self.rows(grey, window, out, offset, step, |s, v| {
                    2 * s as i32 >= n * (2 * (i32::from(v) + delta) - 1)
                })
            }
        }
    }

    /// [`MeanThreshold::binary_inv`] with `dark(s, v)` saying whether a
    /// pixel of value `v` whose window sums to `s` is foreground: one loop
    /// per rounding, so that each vectorises.
    #[inline(always)]
    fn rows(
        &self,
        grey: &[u8],
        window: usize,
        out: &mut [u8],
        offset: usize,
        step: usize,
        dark: impl Fn(u32, u8) -> bool,
    ) {
        let (width, height) = (self.width, self.height);
        let r = window / 2;
        let iw = self.width + 2 * self.pad + 1;
        for y in 0..height {
            // Padded rows y - r .. y + r: integral rows y + pad - r and y + pad + r + 1.
            let top = &self.integral[(y + self.pad - r) * iw..][..iw];
            let bottom = &self.integral[(y + self.pad + r + 1) * iw..][..iw];
            let x0 = self.pad - r;
            let src = &grey[y * self.stride..y * self.stride + width];
            let dst = &mut out[offset + y * step..offset + y * step + width];
            let (ta, tb) = (&top[x0..x0 + width], &top[x0 + window..x0 + window + width]);
            let (ba, bb) = (
                &bottom[x0..x0 + width],
                &bottom[x0 + window..x0 + window + width],
            );
            for x in 0..width {
                let s = bb[x]
                    .wrapping_sub(ba[x])
                    .wrapping_sub(tb[x])
                    .wrapping_add(ta[x]);
                dst[x] = u8::from(dark(s, src[x]));
            }
        }
    }
}

/// The fixed point's shift in OpenCV's `ColumnSum<ushort, uchar>`: its
/// products stay under 255 * 2^23, within 32 bits.
const SHIFT: u32 = 23;
/// The largest window, pixels a side: its sums and their products with the
/// window's size stay within 32 bits.
pub const MAX_WINDOW: usize = 181;

/// OpenCV's rounding of a window's sum to its mean.
#[derive(Debug, Clone, Copy)]
enum Mean {
    /// `(s + delta) * scale >> 23`: 16-bit sums (windows of up to 256 pixels).
    FixedPoint { delta: u32, scale: u32 },
    /// The nearest integer to `s / n` (OpenCV's 32-bit sums, for larger
    /// windows).
    Nearest,
}

impl Mean {
    fn new(n: u32) -> Self {
        if n <= 256 {
            // OpenCV's ColumnSum<ushort, uchar>.
            let scalef = f64::from(1u32 << SHIFT) / f64::from(n);
            let mut scale = scalef.floor() as u32;
            let mut delta = n / 2;
            if scalef - f64::from(scale) < 0.5 {
                delta += 1;
            } else {
                scale += 1;
            }
            Mean::FixedPoint { delta, scale }
        } else {
            Mean::Nearest
        }
    }
}
