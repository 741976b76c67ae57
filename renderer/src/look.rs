//! What the simulated camera's images look like: the scene around the
//! marker cards and what a real camera and mirror add to it.
//!
//! Three presets: `realistic` (the default: a lit room, the mirror's frame,
//! the robot's body and arm, printed distractors; defocus, motion blur,
//! vignetting, photon and read noise, the mirror's reflectance and its
//! second-surface ghost), `clean` (cards on a flat grey field, light blur
//! and noise: the renderer of earlier versions) and `sharp` (`clean`
//! without blur or noise, for tests of the detector's geometry).

pub use stages::camera::LookName;

/// The simulated camera's image model. Grey levels are the sensor's digital
/// numbers (DN, 0-255).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Look {
    /// A lit, textured room with the mirror's frame, the robot's head and
    /// body, printed distractors and the arm's links; else a flat field of
    /// `background_dn`.
    pub room: bool,
    /// The flat field's level without a room, DN.
    pub background_dn: f64,
    /// Reflectance of the cards' black print and white paper.
    pub paper: [f64; 2],
    /// DN of a white (reflectance 1) surface under the scene's reference
    /// illumination (the flat field: reflectance 1 is 255).
    pub exposure_dn: f64,
    /// Stray light over the whole image (lens flare), DN.
    pub flare_dn: f64,
    /// Blur of the optics at best focus, Gaussian sigma, px.
    pub optics_blur_px: f64,
    /// Defocus: the blur sigma is `defocus_px_mm * |1/depth - 1/focus_mm|` px.
    pub defocus_px_mm: f64,
    /// Focus distance, mm.
    pub focus_mm: f64,
    /// Exposure time, ms: the arm's motion over it blurs the arm.
    pub exposure_ms: f64,
    /// Brightness at the image corners relative to the centre (1: none).
    pub vignetting: f64,
    /// Fraction of light the mirror reflects.
    pub reflectance: f64,
    /// Strength of the glass's front-surface reflection relative to the
    /// silvered back (the ghost image); 0 for none.
    pub ghost: f64,
    /// How far the ghost image sits from the main reflection, along the
    /// mirror's normal, mm (twice the glass's apparent thickness).
    pub ghost_offset_mm: f64,
    /// Read noise, DN (standard deviation).
    pub read_noise_dn: f64,
    /// Photo-electrons per DN (photon noise is Poisson in electrons); 0 for
    /// no photon noise.
    pub electrons_per_dn: f64,
    /// Compress each image with JPEG at this quality, as a USB camera's
    /// MJPEG stream does.
    pub jpeg_quality: Option<u8>,
}

impl Look {
    /// The preset `name`'s parameters.
    pub fn named(name: LookName) -> Self {
        match name {
            LookName::Realistic => Look::realistic(),
            LookName::Clean => Look::clean(),
            LookName::Sharp => Look::sharp(),
        }
    }

    /// Cards on a flat grey field, light blur and noise (the earlier renderer).
    pub fn clean() -> Self {
        Self {
            room: false,
            background_dn: 110.0,
            paper: [0.0, 1.0],
            exposure_dn: 255.0,
            flare_dn: 0.0,
            optics_blur_px: 0.6,
            defocus_px_mm: 0.0,
            focus_mm: 800.0,
            exposure_ms: 0.0,
            vignetting: 1.0,
            reflectance: 1.0,
            ghost: 0.0,
            ghost_offset_mm: 0.0,
            read_noise_dn: 2.0,
            electrons_per_dn: 0.0,
            jpeg_quality: None,
        }
    }

    /// [`Look::clean`] without blur or noise.
    pub fn sharp() -> Self {
        Self {
            optics_blur_px: 0.0,
            read_noise_dn: 0.0,
            ..Self::clean()
        }
    }

    /// A small robot's stereo head of webcam modules in an indoor room: a
    /// fixed-focus lens at 0.8 m that blurs by 1.5 px at best focus, 8 ms
    /// exposure, 25% darker corners, a silvered float-glass mirror (90%,
    /// ghost 4.5% of it from 4 mm glass), matte paper (black 5%, white
    /// 85%), noise of a small sensor at moderate gain (16 e-/DN, 1.5 DN
    /// read noise). Blur and noise are set so that the tracker's centre errors
    /// fall within those it has on real photographs (checked by the
    /// `tracker_proc` real-image test).
    pub fn realistic() -> Self {
        Self {
            room: true,
            background_dn: 110.0,
            paper: [0.05, 0.85],
            exposure_dn: 250.0,
            flare_dn: 5.0,
            optics_blur_px: 1.5,
            defocus_px_mm: 450.0,
            focus_mm: 800.0,
            exposure_ms: 8.0,
            vignetting: 0.75,
            reflectance: 0.9,
            ghost: 0.045,
            ghost_offset_mm: 2.7,
            read_noise_dn: 1.5,
            electrons_per_dn: 16.0,
            jpeg_quality: None,
        }
    }

    /// Blur sigma of something at `depth` mm (optics and defocus), px.
    pub fn blur_at(&self, depth: f64) -> f64 {
        let defocus = self.defocus_px_mm * (1.0 / depth.max(1.0) - 1.0 / self.focus_mm).abs();
        self.optics_blur_px.hypot(defocus)
    }

    /// Checks the parameters; the error names the first one out of range.
    pub fn validate(&self) -> Result<(), crate::RenderError> {
        let fraction = |v: f64| (0.0..=1.0).contains(&v);
        let checks: [(&str, bool); 11] = [
            (
                "paper",
                fraction(self.paper[0]) && fraction(self.paper[1]) && self.paper[0] < self.paper[1],
            ),
            (
                "exposure_dn",
                self.exposure_dn > 0.0 && self.exposure_dn.is_finite(),
            ),
            ("flare_dn", (0.0..=255.0).contains(&self.flare_dn)),
            (
                "optics_blur_px",
                (0.0..=10.0).contains(&self.optics_blur_px),
            ),
            ("defocus", self.defocus_px_mm >= 0.0 && self.focus_mm > 0.0),
            ("exposure_ms", (0.0..=1000.0).contains(&self.exposure_ms)),
            (
                "vignetting",
                self.vignetting > 0.0 && self.vignetting <= 1.0,
            ),
            (
                "reflectance",
                self.reflectance > 0.0 && self.reflectance <= 1.0,
            ),
            (
                "ghost",
                fraction(self.ghost) && self.ghost_offset_mm.is_finite(),
            ),
            (
                "noise",
                self.read_noise_dn >= 0.0 && self.electrons_per_dn >= 0.0,
            ),
            (
                "jpeg_quality",
                self.jpeg_quality.is_none_or(|q| (1..=100).contains(&q)),
            ),
        ];
        match checks.iter().find(|(_, ok)| !ok) {
            Some((name, _)) => Err(crate::RenderError::BadLook(name)),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_named_both_ways() {
        for name in LookName::ALL {
            Look::named(name).validate().unwrap();
            assert_eq!(name.as_str().parse::<LookName>().unwrap(), name);
        }
        assert!("glossy".parse::<LookName>().is_err());
        let bad = Look {
            reflectance: 1.5,
            ..Look::realistic()
        };
        assert_eq!(
            bad.validate().unwrap_err().to_string(),
            "look parameter reflectance is out of range"
        );
    }

    #[test]
    fn defocus_grows_away_from_the_focus() {
        let look = Look::realistic();
        let at_focus = look.blur_at(800.0);
        assert!((at_focus - look.optics_blur_px).abs() < 1e-12);
        assert!(look.blur_at(300.0) > look.blur_at(500.0));
        assert!(look.blur_at(3000.0) > at_focus);
    }
}
