//! OpenCV's lens distortion model on normalised image coordinates:
//! radial (`k1..k6`, rational when `k4..k6` are non-zero) and tangential
//! (`p1, p2`), the model of `cv::projectPoints`, ROS's `plumb_bob` (5
//! coefficients) and `rational_polynomial` (8):
//!
//! ```text
//! r² = x² + y²
//! s  = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
//! x' = x s + 2 p1 x y + p2 (r² + 2 x²)
//! y' = y s + p1 (r² + 2 y²) + 2 p2 x y
//! ```

use nalgebra::{Matrix2, Vector2};
use serde::{Deserialize, Serialize};

use crate::GeometryError;

/// Distortion coefficients in OpenCV's order `k1, k2, p1, p2, k3, k4, k5, k6`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Distortion {
    /// First radial coefficient (`r²`).
    pub k1: f64,
    /// Second radial coefficient (`r⁴`).
    pub k2: f64,
    /// First tangential coefficient.
    pub p1: f64,
    /// Second tangential coefficient.
    pub p2: f64,
    /// Third radial coefficient (`r⁶`).
    pub k3: f64,
    /// First denominator coefficient of the rational model (`r²`).
    pub k4: f64,
    /// Second denominator coefficient of the rational model (`r⁴`).
    pub k5: f64,
    /// Third denominator coefficient of the rational model (`r⁶`).
    pub k6: f64,
}

/// The distortion models named by ROS `camera_info` and OpenCV.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DistortionModel {
    /// `k1, k2, p1, p2, k3`.
    PlumbBob,
    /// `k1, k2, p1, p2, k3, k4, k5, k6`.
    RationalPolynomial,
}

impl DistortionModel {
    /// The name ROS's `camera_info` uses.
    pub fn ros_name(self) -> &'static str {
        match self {
            Self::PlumbBob => "plumb_bob",
            Self::RationalPolynomial => "rational_polynomial",
        }
    }

    /// How many coefficients the model has.
    pub fn coefficient_count(self) -> usize {
        match self {
            Self::PlumbBob => 5,
            Self::RationalPolynomial => 8,
        }
    }
}

impl Distortion {
    /// Radial distortion with two terms (Zhang 2000).
    pub fn radial(k1: f64, k2: f64) -> Self {
        Self {
            k1,
            k2,
            ..Self::default()
        }
    }

    /// Coefficients in OpenCV's order: 4 (`k1, k2, p1, p2`), 5 (plus `k3`)
    /// or 8 (plus `k4, k5, k6`); an empty slice is no distortion.
    pub fn from_opencv(c: &[f64]) -> Result<Self, GeometryError> {
        if !matches!(c.len(), 0 | 4 | 5 | 8) {
            return Err(GeometryError::Degenerate(format!(
                "{} distortion coefficients; expected 4, 5 (k1, k2, p1, p2, k3) or 8 (… k4, k5, k6)",
                c.len()
            )));
        }
        if !c.iter().all(|v| v.is_finite()) {
            return Err(GeometryError::NonFinite("distortion coefficients"));
        }
        let at = |i: usize| c.get(i).copied().unwrap_or(0.0);
        Ok(Self {
            k1: at(0),
            k2: at(1),
            p1: at(2),
            p2: at(3),
            k3: at(4),
            k4: at(5),
            k5: at(6),
            k6: at(7),
        })
    }

    /// All eight coefficients in OpenCV's order.
    pub fn to_opencv(&self) -> [f64; 8] {
        [
            self.k1, self.k2, self.p1, self.p2, self.k3, self.k4, self.k5, self.k6,
        ]
    }

    /// The smallest standard model that holds these coefficients.
    pub fn model(&self) -> DistortionModel {
        if self.k4 == 0.0 && self.k5 == 0.0 && self.k6 == 0.0 {
            DistortionModel::PlumbBob
        } else {
            DistortionModel::RationalPolynomial
        }
    }

    /// The coefficients of [`Self::model`]: 5 or 8 numbers.
    pub fn coefficients(&self) -> Vec<f64> {
        self.to_opencv()[..self.model().coefficient_count()].to_vec()
    }

    /// Whether only `k1` and `k2` may be non-zero.
    pub fn is_two_term_radial(&self) -> bool {
        self.to_opencv()[2..].iter().all(|&v| v == 0.0)
    }

    /// The radial factor `s` and its derivative by `r²`.
    fn radial_factor(&self, r2: f64) -> (f64, f64) {
        let num = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let den = 1.0 + r2 * (self.k4 + r2 * (self.k5 + r2 * self.k6));
        let dnum = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let dden = self.k4 + r2 * (2.0 * self.k5 + 3.0 * r2 * self.k6);
        (num / den, (dnum * den - num * dden) / (den * den))
    }

    /// Undistorted to distorted normalised coordinates.
    pub fn distort(&self, xy: &Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (xy.x, xy.y);
        let r2 = x * x + y * y;
        let (s, _) = self.radial_factor(r2);
        Vector2::new(
            x * s + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * s + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// `d distort / d xy` at `xy`, a 2x2 matrix (rows: x', y').
    pub fn jacobian(&self, xy: &Vector2<f64>) -> Matrix2<f64> {
        let (x, y) = (xy.x, xy.y);
        let (s, ds) = self.radial_factor(x * x + y * y);
        // d x'/dy and d y'/dx are the same expression.
        let off = 2.0 * x * y * ds + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        Matrix2::new(
            s + 2.0 * x * x * ds + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
            off,
            off,
            s + 2.0 * y * y * ds + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
        )
    }

    /// Distorted to undistorted normalised coordinates: Newton's method on
    /// [`Self::distort`] with its exact Jacobian, from the distorted point.
    /// Fails where the model folds over (its Jacobian is singular) or the
    /// iteration does not reach 1e-10.
    pub fn undistort(&self, distorted: &Vector2<f64>) -> Option<Vector2<f64>> {
        let mut xy = *distorted;
        for _ in 0..50 {
            let residual = self.distort(&xy) - distorted;
            if residual.norm() < 1e-14 {
                return Some(xy);
            }
            let step = self.jacobian(&xy).try_inverse()? * residual;
            // Damp steps that would jump far: the rational model has poles.
            let limit = 0.5 * (1.0 + xy.norm());
            xy -= if step.norm() > limit {
                step * (limit / step.norm())
            } else {
                step
            };
            if !(xy.x.is_finite() && xy.y.is_finite()) {
                return None;
            }
        }
        ((self.distort(&xy) - distorted).norm() < 1e-10).then_some(xy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A plumb_bob lens and a rational wide-angle lens, as calibrations give them.
    pub(crate) fn lenses() -> [Distortion; 2] {
        [
            Distortion::from_opencv(&[-0.28, 0.09, 0.0012, -0.0007, -0.011]).unwrap(),
            Distortion::from_opencv(&[0.42, -0.05, 0.0009, 0.0004, 0.002, 0.78, 0.06, 0.01])
                .unwrap(),
        ]
    }

    proptest! {
        #[test]
        fn jacobian_matches_central_differences(x in -0.7..0.7f64, y in -0.55..0.55f64, lens in 0..2usize) {
            let d = lenses()[lens];
            let p = Vector2::new(x, y);
            let h = 1e-6;
            let mut numeric = Matrix2::zeros();
            for c in 0..2 {
                let mut e = Vector2::zeros();
                e[c] = h;
                numeric.set_column(c, &((d.distort(&(p + e)) - d.distort(&(p - e))) / (2.0 * h)));
            }
            prop_assert!((d.jacobian(&p) - numeric).norm() < 1e-7, "{} vs {}", d.jacobian(&p), numeric);
        }

        #[test]
        fn undistort_inverts_distort(x in -0.7..0.7f64, y in -0.55..0.55f64, lens in 0..2usize) {
            let d = lenses()[lens];
            let p = Vector2::new(x, y);
            let back = d.undistort(&d.distort(&p)).unwrap();
            prop_assert!((back - p).norm() < 1e-10, "{back} vs {p}");
        }
    }

    #[test]
    fn coefficient_lists_follow_opencv_order() {
        let d = Distortion::from_opencv(&[1.0, 2.0, 3.0, 4.0, 5.0]).unwrap();
        assert_eq!(
            (d.k1, d.k2, d.p1, d.p2, d.k3, d.k4),
            (1.0, 2.0, 3.0, 4.0, 5.0, 0.0)
        );
        assert_eq!(d.model(), DistortionModel::PlumbBob);
        assert_eq!(d.coefficients(), vec![1.0, 2.0, 3.0, 4.0, 5.0]);
        let r = Distortion::from_opencv(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0]).unwrap();
        assert_eq!(r.model(), DistortionModel::RationalPolynomial);
        assert_eq!(r.coefficients().len(), 8);
        assert!(Distortion::from_opencv(&[1.0, 2.0, 3.0]).is_err());
        assert!(Distortion::from_opencv(&[1.0, f64::NAN, 0.0, 0.0]).is_err());
        assert!(Distortion::radial(0.1, 0.2).is_two_term_radial());
        assert!(!d.is_two_term_radial());
    }
}
