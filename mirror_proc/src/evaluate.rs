//! The paper's error metrics for a set of mirror cameras.
//!
//! - mirror 3D: mirror-view detections triangulated through the mirror
//!   cameras, against the end-effector model `J`;
//! - mirror 2D: `J` projected through the mirror cameras, against the
//!   detections (Euclidean distance per camera, averaged over both);
//! - direct 3D / 2D: the same for direct views through the real cameras.
//!
//! Joint offsets, when given, are applied to the end-effector model.

use formats::evaluation::Evaluation;
use geometry::triangulate::{mean_reprojection_error, triangulate};
use geometry::{Camera, Rig, Sample, View};
use nalgebra::Vector3;

use crate::calibrate::{CalibrateError, model_point};

/// Per-sample errors of one view kind.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Errors {
    /// 3D errors, mm.
    pub mm: Vec<f64>,
    /// 2D errors, px.
    pub px: Vec<f64>,
}

impl Errors {
    /// Adds one sample's errors given the cameras, the reference point and the detections.
    fn push(
        &mut self,
        cameras: [&Camera; 2],
        reference: &Vector3<f64>,
        sample: &Sample,
    ) -> Result<(), CalibrateError> {
        let bad = |what: &str, e: geometry::GeometryError| CalibrateError::BadSample {
            pose: sample.pose,
            reason: format!("cannot {what}: {e}"),
        };
        let reconstructed =
            triangulate(cameras, sample.pixels).map_err(|e| bad("triangulate", e))?;
        let px = mean_reprojection_error(cameras, sample.pixels, reference)
            .map_err(|e| bad("project", e))?;
        self.mm.push((reconstructed - reference).norm());
        self.px.push(px);
        Ok(())
    }
}

/// Mirror and direct errors of a calibration on some samples.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SampleErrors {
    /// Mirror-view samples.
    pub mirror: Errors,
    /// Direct-view samples.
    pub direct: Errors,
}

impl SampleErrors {
    /// The report of means, medians and counts.
    pub fn summary(&self) -> Evaluation {
        Evaluation::from_errors(
            &self.mirror.mm,
            &self.mirror.px,
            &self.direct.mm,
            &self.direct.px,
        )
    }
}

/// Errors of `mirror_cameras` (and the model with `joint_offsets`) on `samples`,
/// with the end-effector model as the reference.
pub fn evaluate(
    rig: &Rig,
    mirror_cameras: &[Camera; 2],
    joint_offsets: Option<&[f64]>,
    samples: &[Sample],
) -> Result<SampleErrors, CalibrateError> {
    let references = samples
        .iter()
        .map(|s| model_point(rig, s, joint_offsets))
        .collect::<Result<Vec<_>, _>>()?;
    evaluate_against(rig, mirror_cameras, samples, &references)
}

/// Errors of `mirror_cameras` on `samples` against given reference points
/// (e.g. the simulator's true positions, for the noise floor).
pub fn evaluate_against(
    rig: &Rig,
    mirror_cameras: &[Camera; 2],
    samples: &[Sample],
    references: &[Vector3<f64>],
) -> Result<SampleErrors, CalibrateError> {
    let mut out = SampleErrors::default();
    for (s, reference) in samples.iter().zip(references) {
        match s.view {
            View::Mirror => {
                out.mirror
                    .push([&mirror_cameras[0], &mirror_cameras[1]], reference, s)?
            }
            View::Direct => out.direct.push(rig.camera_refs(), reference, s)?,
        }
    }
    Ok(out)
}
