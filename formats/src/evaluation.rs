//! The evaluation report (JSON on stdout): the paper's four mean errors,
//! with medians and counts. A metric without samples is `null`.

use serde::{Deserialize, Serialize};

/// Summary of one error metric over a set of samples.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    /// Mean.
    pub mean: f64,
    /// Median.
    pub median: f64,
    /// Number of samples.
    pub count: usize,
}

impl Stat {
    /// Mean, median and count of `values`; `None` when empty.
    pub fn of(values: &[f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        let n = sorted.len();
        let median = if n % 2 == 1 {
            sorted[n / 2]
        } else {
            0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
        };
        Some(Self {
            mean: values.iter().sum::<f64>() / n as f64,
            median,
            count: n,
        })
    }
}

/// The paper's metrics for one calibration on one set of samples.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    /// Mean 3D error (mm) of mirror views reconstructed through the mirror cameras, against the model.
    pub mirror_3d_mm: Option<f64>,
    /// Mean 2D error (px) of the model projected through the mirror cameras, against the detections.
    pub mirror_2d_px: Option<f64>,
    /// Mean 3D error (mm) of direct views reconstructed through the real cameras.
    pub direct_3d_mm: Option<f64>,
    /// Mean 2D error (px) of the model projected through the real cameras.
    pub direct_2d_px: Option<f64>,
    /// Median of `mirror_3d_mm`'s per-sample errors.
    pub mirror_3d_mm_median: Option<f64>,
    /// Median of `mirror_2d_px`'s per-sample errors.
    pub mirror_2d_px_median: Option<f64>,
    /// Median of `direct_3d_mm`'s per-sample errors.
    pub direct_3d_mm_median: Option<f64>,
    /// Median of `direct_2d_px`'s per-sample errors.
    pub direct_2d_px_median: Option<f64>,
    /// Mirror samples evaluated.
    pub mirror_count: usize,
    /// Direct samples evaluated.
    pub direct_count: usize,
}

impl Evaluation {
    /// Builds the report from per-sample errors.
    pub fn from_errors(
        mirror_3d: &[f64],
        mirror_2d: &[f64],
        direct_3d: &[f64],
        direct_2d: &[f64],
    ) -> Self {
        let (m3, m2, d3, d2) = (
            Stat::of(mirror_3d),
            Stat::of(mirror_2d),
            Stat::of(direct_3d),
            Stat::of(direct_2d),
        );
        Self {
            mirror_3d_mm: m3.map(|s| s.mean),
            mirror_2d_px: m2.map(|s| s.mean),
            direct_3d_mm: d3.map(|s| s.mean),
            direct_2d_px: d2.map(|s| s.mean),
            mirror_3d_mm_median: m3.map(|s| s.median),
            mirror_2d_px_median: m2.map(|s| s.median),
            direct_3d_mm_median: d3.map(|s| s.median),
            direct_2d_px_median: d2.map(|s| s.median),
            mirror_count: mirror_2d.len(),
            direct_count: direct_2d.len(),
        }
    }

    /// Renders as pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("an evaluation always serialises") + "\n"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_and_nulls() {
        let s = Stat::of(&[3.0, 1.0, 2.0, 10.0]).unwrap();
        assert_eq!((s.mean, s.median, s.count), (4.0, 2.5, 4));
        let e = Evaluation::from_errors(&[1.0], &[2.0], &[], &[]);
        let json = e.to_json();
        assert!(json.contains("\"direct_3d_mm\": null"), "{json}");
    }
}
