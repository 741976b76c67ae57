//! What the image sensor and the camera's electronics add: vignetting,
//! photon and read noise, and optional MJPEG compression.

use crate::Result;
use opencv::core::{Mat, Vector};
use opencv::imgcodecs;
use opencv::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::look::Look;

/// Fixed-point scale of the noise table: entries are N(0, 1) * 32.
const TABLE_SCALE: f64 = 32.0;

/// Relative brightness per pixel: 1 at the principal point, `corner` at the
/// farthest image corner, falling as `1 / (1 + a r^2)^2` (the cos^4 law's shape).
pub fn vignetting(width: usize, height: usize, center: [f64; 2], corner: f64) -> Vec<f32> {
    let far = [
        [0.0, 0.0],
        [width as f64, 0.0],
        [0.0, height as f64],
        [width as f64, height as f64],
    ]
    .iter()
    .map(|c| (c[0] - center[0]).hypot(c[1] - center[1]))
    .fold(0.0, f64::max);
    let a = corner.powf(-0.5) - 1.0;
    let mut gain = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            let r = (x as f64 + 0.5 - center[0]).hypot(y as f64 + 0.5 - center[1]) / far;
            gain.push((1.0 / (1.0 + a * r * r).powi(2)) as f32);
        }
    }
    gain
}

/// Sensor noise: a table of standard normal draws, read at a seeded offset
/// per image and scaled per pixel by the noise at its level.
pub struct Noise {
    /// N(0, 1) * [`TABLE_SCALE`], saturated to i8.
    table: Vec<i8>,
    /// The noisy level for each (level, draw): `level << 8 | draw as u8`
    /// indexes it; one lookup a pixel instead of a multiply, a shift and a
    /// clamp.
    noisy: Vec<u8>,
    pixels: usize,
    quality: Option<u8>,
}

impl Noise {
    /// Noise for images of `pixels` pixels as `look` says; `seed` fixes the table.
    pub fn new(look: &Look, pixels: usize, seed: u64) -> Self {
        // Per grey level: its noise sigma * 256 / TABLE_SCALE.
        let mut sigma = [0i32; 256];
        for (level, s) in sigma.iter_mut().enumerate() {
            let signal = (level as f64 - look.flare_dn).max(0.0);
            let photon = if look.electrons_per_dn > 0.0 {
                signal / look.electrons_per_dn
            } else {
                0.0
            };
            let dn = (look.read_noise_dn.powi(2) + photon).sqrt();
            *s = (dn * 256.0 / TABLE_SCALE).round() as i32;
        }
        let silent = sigma.iter().all(|&s| s == 0);
        let table = if silent {
            Vec::new()
        } else {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            // Twice an image and a little more, so offsets vary.
            (0..2 * pixels + 4099)
                .map(|_| {
                    let n: f64 = StandardNormal.sample(&mut rng);
                    (n * TABLE_SCALE).round().clamp(-127.0, 127.0) as i8
                })
                .collect()
        };
        // Each level with each draw at that level's sigma.
        let noisy = (0..256 * 256)
            .map(|i: usize| {
                let (level, draw) = ((i >> 8) as i32, i32::from((i & 0xff) as u8 as i8));
                let v = level + ((draw * sigma[level as usize] + 128) >> 8);
                v.clamp(0, 255) as u8
            })
            .collect();
        Self {
            table,
            noisy,
            pixels,
            quality: look.jpeg_quality,
        }
    }

    /// Whether it adds no noise (the look has none).
    pub fn is_silent(&self) -> bool {
        self.table.is_empty()
    }

    /// Adds noise to `pixels` (an image or part of one, at most as many
    /// pixels as the noise was made for), from the table at an offset drawn
    /// from `seed`.
    pub fn add(&self, pixels: &mut [u8], seed: u64) {
        if self.table.is_empty() {
            return;
        }
        let span = self.table.len() - pixels.len().min(self.pixels);
        let offset = (splitmix(seed) % span as u64) as usize;
        let draws = &self.table[offset..];
        for (p, &n) in pixels.iter_mut().zip(draws) {
            *p = self.noisy[usize::from(*p) << 8 | usize::from(n as u8)];
        }
    }

    /// Compresses `image` as MJPEG would, if the look says so.
    pub fn compress(&self, image: &mut [u8], width: usize) -> Result<()> {
        if let Some(quality) = self.quality {
            jpeg_round_trip(image, width, quality)?;
        }
        Ok(())
    }
}

/// One step of splitmix64: spreads consecutive seeds over the table.
fn splitmix(seed: u64) -> u64 {
    let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Encodes `image` as JPEG at `quality` and decodes it back in place.
fn jpeg_round_trip(image: &mut [u8], width: usize, quality: u8) -> Result<()> {
    let height = image.len() / width;
    let mat = Mat::new_rows_cols_with_data(height as i32, width as i32, &*image)?;
    let mut bytes = Vector::<u8>::new();
    let params = Vector::from_slice(&[imgcodecs::IMWRITE_JPEG_QUALITY, i32::from(quality)]);
    imgcodecs::imencode(".jpg", &mat, &mut bytes, &params)?;
    let decoded = imgcodecs::imdecode(&bytes, imgcodecs::IMREAD_GRAYSCALE)?;
    image.copy_from_slice(decoded.data_bytes()?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vignetting_is_one_at_the_centre_and_the_corner_value_at_the_far_corner() {
        let gain = vignetting(101, 51, [50.5, 25.5], 0.75);
        assert!((gain[25 * 101 + 50] - 1.0).abs() < 1e-3);
        assert!((gain[0] - 0.75).abs() < 0.01, "{}", gain[0]);
    }

    #[test]
    fn noise_has_the_sigma_of_its_level() {
        let look = Look::realistic();
        let n = 200_000;
        let noise = Noise::new(&look, n, 3);
        for level in [20u8, 120, 220] {
            let mut image = vec![level; n];
            noise.add(&mut image, 11);
            let mean = image.iter().map(|&v| f64::from(v)).sum::<f64>() / n as f64;
            let var = image
                .iter()
                .map(|&v| (f64::from(v) - mean).powi(2))
                .sum::<f64>()
                / n as f64;
            let expect = (look.read_noise_dn.powi(2)
                + (f64::from(level) - look.flare_dn) / look.electrons_per_dn)
                .sqrt();
            assert!(
                (mean - f64::from(level)).abs() < 0.1,
                "mean {mean} at {level}"
            );
            // Rounding to whole DN adds 1/12 of a DN^2.
            let sigma = (var - 1.0 / 12.0).sqrt();
            assert!(
                (sigma / expect - 1.0).abs() < 0.05,
                "sigma {sigma} vs {expect} at {level}"
            );
        }
        let (mut a, mut b) = (vec![100u8; n], vec![100u8; n]);
        noise.add(&mut a, 1);
        noise.add(&mut b, 2);
        assert_ne!(a, b, "seeds give different noise");
    }

    #[test]
    fn jpeg_keeps_the_picture_and_changes_the_pixels() {
        let look = Look {
            jpeg_quality: Some(60),
            ..Look::sharp()
        };
        let noise = Noise::new(&look, 64 * 64, 0);
        let mut image: Vec<u8> = (0..64 * 64)
            .map(|i| if (i % 64) / 8 % 2 == 0 { 30 } else { 220 })
            .collect();
        let before = image.clone();
        noise.add(&mut image, 0);
        noise.compress(&mut image, 64).unwrap();
        assert_ne!(image, before);
        let diff = image
            .iter()
            .zip(&before)
            .map(|(a, b)| (i32::from(*a) - i32::from(*b)).abs())
            .sum::<i32>();
        assert!(f64::from(diff) / (64.0 * 64.0) < 10.0);
    }
}
