//! Estimating the mirror-perspective cameras from mirror-view samples.
//!
//! Three methods ([`Method`]):
//! - `paper`: Hart & Scassellati (2012), per camera: mirror plane from the
//!   `J`/`Ĵ` pairs (Eqs 6-9), initial camera (Eqs 10-12), 6-DOF
//!   Levenberg-Marquardt on reprojection error (Eq 13);
//! - `joint`: one mirror plane (3 DOF) shared by both cameras, both mirror
//!   cameras derived from it and the known rig, refined on both cameras'
//!   reprojection errors;
//! - `joint+kinematics`: the joint plane plus per-joint encoder offsets.
//!
//! The joint methods also calibrate across several mirror placements (one
//! plane each, the same cameras and arm), use direct views as constraints
//! on the arm, and may estimate the arm's base and tool ([`Estimate`]).

mod joint;
mod paper;
pub mod uncertainty;

pub use paper::initial_estimate as paper_initial_estimate;
pub use uncertainty::Uncertainty;

use geometry::{Camera, GeometryError, Plane, Rig, Sample, View, triangulate::triangulate};
use nalgebra::{Isometry3, Vector2, Vector3};

/// Fewest mirror samples any method accepts.
pub const MIN_SAMPLES: usize = 3;
/// Smallest RMS spread (mm) of the end-effector positions around their mean:
/// below it the poses are "all nearly the same" and the mirror camera's
/// pose is not determined.
pub const MIN_SPREAD_MM: f64 = 10.0;
/// Closest a camera may be to the estimated mirror plane, mm.
pub const MIN_CAMERA_PLANE_DISTANCE_MM: f64 = 1.0;
/// Smallest angle (median over the samples) at which the cameras' rays to
/// the reflections may meet the mirror: below it the mirror is seen edge-on
/// and its plane is not determined along the rays.
pub const MIN_GRAZING_DEG: f64 = 5.0;
/// The detections' noise (px per coordinate, 1 sigma) a fit is judged
/// against when neither the rig nor the caller states one: our tracker's
/// centre errors on renders, median 0.109 px and 95th percentile 0.40 px
/// (docs/methods.md), rounded up. Live calibrations on renders leave
/// 0.05-0.08 px.
pub const TRACKER_PIXEL_SIGMA: f64 = 0.2;

pub use formats::calibration::{FitVerdict, Method};

/// Why a calibration could not be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrateError {
    /// Not enough mirror samples.
    #[error("{found} usable mirror samples; at least {MIN_SAMPLES} are needed")]
    TooFewSamples {
        /// Mirror samples found.
        found: usize,
    },
    /// The poses do not spread enough to determine the mirror camera.
    #[error(
        "the arm poses are nearly all the same (end-effector spread {spread_mm:.2} mm, need {MIN_SPREAD_MM} mm)"
    )]
    PosesAlike {
        /// RMS spread of the end-effector positions, mm.
        spread_mm: f64,
    },
    /// A sample lacks what the method needs.
    #[error("pose {pose}: {reason}")]
    BadSample {
        /// Pose id.
        pose: u64,
        /// What is missing or wrong.
        reason: String,
    },
    /// The estimated mirror passes through (or too close to) a camera.
    #[error("the estimated mirror plane passes within {distance_mm:.3} mm of the {camera} camera")]
    PlaneThroughCamera {
        /// Camera name.
        camera: String,
        /// Its distance to the plane.
        distance_mm: f64,
    },
    /// The mirror is seen edge-on.
    #[error(
        "the mirror is seen edge-on: the cameras' rays meet it at {grazing_deg:.1} deg (median), need {MIN_GRAZING_DEG} deg"
    )]
    MirrorEdgeOn {
        /// Median angle between the rays and the plane, degrees.
        grazing_deg: f64,
    },
    /// The geometry does not determine a solution.
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    /// Something asked to be estimated cannot be from these samples, or
    /// with this method or rig.
    #[error("cannot estimate {what}: {why}")]
    CannotEstimate {
        /// What was to be estimated.
        what: String,
        /// Why not, and what would help.
        why: String,
    },
    /// An error in one placement's samples, when there are several.
    #[error("placement {placement}: {source}")]
    InPlacement {
        /// Index of the placement (its samples file).
        placement: usize,
        /// The error.
        source: Box<CalibrateError>,
    },
}

/// What a calibration estimates of the arm beside the mirror: its base
/// (`world_from_base`, 6 DOF) and its tool (the marker centre in the last
/// link's frame, 3).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Estimate {
    /// The arm's base placement.
    pub base: bool,
    /// The tool point.
    pub tool: bool,
}

impl Estimate {
    /// Whether anything is estimated.
    pub fn any(self) -> bool {
        self.base || self.tool
    }
}

impl std::str::FromStr for Estimate {
    type Err = String;

    /// `base`, `tool`, `base,tool` (any order), or `none`.
    fn from_str(list: &str) -> Result<Self, String> {
        let mut out = Estimate::default();
        for part in list.split(',').map(str::trim) {
            match part {
                "base" => out.base = true,
                "tool" => out.tool = true,
                "none" | "" => {}
                other => {
                    return Err(format!(
                        "unknown quantity `{other}`: expected base, tool or base,tool"
                    ));
                }
            }
        }
        Ok(out)
    }
}

/// A computed calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// The method that produced it.
    pub method: Method,
    /// The mirror plane (normal towards the robot), for `joint` methods.
    pub plane: Option<Plane>,
    /// The mirror-perspective cameras (proper rotations), left then right.
    pub mirror_cameras: [Camera; 2],
    /// Estimated encoder offsets (rad), for `joint+kinematics`.
    pub joint_offsets: Option<Vec<f64>>,
    /// The estimate the refinement started from (mirror cameras).
    pub initial_cameras: [Camera; 2],
    /// RMS reprojection error over both cameras on the training samples, px.
    pub train_rms_px: f64,
    /// Mirror samples used, over all placements.
    pub samples: usize,
    /// Direct-view samples used as constraints on the arm.
    pub direct_samples: usize,
    /// Every placement, the first of which is `plane` and `mirror_cameras`.
    pub placements: Vec<PlacementFit>,
    /// The arm's base placement, when estimated.
    pub world_from_base: Option<Isometry3<f64>>,
    /// The tool point in the last link's frame, mm, when estimated.
    pub tool: Option<Vector3<f64>>,
    /// Parameters solved for.
    pub parameters: usize,
    /// What the solved values are known to.
    pub uncertainty: Uncertainty,
    /// Samples set aside as not fitting the others (a wrong pairing, a
    /// misread marker), with their residuals under this calibration.
    pub rejected: Vec<RejectedSample>,
    /// Whether the samples kept fit the model to the expected noise.
    pub fit: Fit,
}

/// One mirror placement of a calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct PlacementFit {
    /// Its mirror plane, for `joint` methods.
    pub plane: Option<Plane>,
    /// Its mirror-perspective cameras, left then right.
    pub mirror_cameras: [Camera; 2],
    /// Its mirror samples used.
    pub samples: usize,
}

/// How well a calibration's model explains its samples, judged against the
/// detections' expected noise.
#[derive(Debug, Clone, PartialEq)]
pub enum Fit {
    /// The residuals are what the noise explains.
    Good,
    /// The residuals are larger than the noise explains: the calibration
    /// stands, but its figures are not to be trusted.
    Poor {
        /// The likely cause, one line.
        cause: String,
    },
    /// Not judged (the caller did not ask).
    NotJudged,
}

/// A sample set aside by the outlier test: its pose id and its RMS
/// reprojection error over both cameras, px (the file's entry as it is).
pub use formats::calibration::RejectedEntry as RejectedSample;

impl Calibration {
    /// The file form of this calibration.
    pub fn to_file(&self, rig: &Rig) -> formats::calibration::CalibrationFile {
        formats::calibration::CalibrationFile::new(
            self.method.as_str(),
            self.plane.as_ref(),
            &rig.names,
            &self.mirror_cameras,
            self.joint_offsets.as_deref(),
            self.train_rms_px,
            self.samples,
        )
        .with_joint_names(rig)
        .with_uncertainty(self.uncertainty.to_file())
        .with_rejected(self.rejected.clone())
        .with_fit(match &self.fit {
            Fit::Good => Some((FitVerdict::Good, None)),
            Fit::Poor { cause } => Some((FitVerdict::Poor, Some(cause.clone()))),
            Fit::NotJudged => None,
        })
        .with_placements(
            &rig.names,
            &self
                .placements
                .iter()
                .filter_map(|p| Some((p.plane?, p.mirror_cameras, p.samples)))
                .collect::<Vec<_>>(),
        )
        .with_arm_estimate(
            self.world_from_base.as_ref(),
            self.tool.as_ref(),
            self.direct_samples,
        )
    }

    /// The rig with this calibration's estimated base and tool in its arm.
    pub fn corrected_rig(&self, rig: &Rig) -> Rig {
        let mut rig = rig.clone();
        if let Some(arm) = rig.arm.as_mut() {
            if let Some(base) = self.world_from_base {
                arm.world_from_base = base;
            }
            if let Some(tool) = self.tool {
                arm.tool = tool;
            }
        }
        rig
    }

    /// Whether the end-effector point comes from the arm's forward
    /// kinematics (offsets, base or tool estimated).
    fn uses_arm(&self) -> bool {
        self.joint_offsets.is_some() || self.world_from_base.is_some() || self.tool.is_some()
    }
}

/// One sample prepared for a solver.
#[derive(Debug, Clone)]
pub(crate) struct Observation {
    /// Its pose id.
    pub pose: u64,
    /// The mirror placement (index of its samples set) it belongs to.
    pub placement: usize,
    /// Seen in the mirror or directly.
    pub view: View,
    /// The end-effector model's prediction `J` (no offsets).
    pub model_point: Vector3<f64>,
    /// Joint readings, when known.
    pub joints: Option<Vec<f64>>,
    /// `Ĵ`: the reflection triangulated through the real cameras (for a
    /// direct view, the marker itself).
    pub reflected_point: Vector3<f64>,
    /// Detections, left then right.
    pub pixels: [Vector2<f64>; 2],
}

/// The end-effector model's position for a sample: `FK(q + offsets)` when
/// offsets are given, else the sample's `jx,jy,jz`, else `FK(q)`.
pub fn model_point(
    rig: &Rig,
    sample: &Sample,
    offsets: Option<&[f64]>,
) -> Result<Vector3<f64>, CalibrateError> {
    let bad = |reason: &str| CalibrateError::BadSample {
        pose: sample.pose,
        reason: reason.to_string(),
    };
    let forward = |offsets: &[f64]| -> Result<Vector3<f64>, CalibrateError> {
        let arm = rig
            .arm
            .as_ref()
            .ok_or_else(|| bad("needs the rig's [arm] to compute J from joint angles"))?;
        let q = sample
            .joints
            .as_ref()
            .ok_or_else(|| bad("has no joint angles (q0..)"))?;
        arm.end_effector(q, offsets)
            .map_err(|e| bad(&e.to_string()))
    };
    match (offsets, sample.model_point) {
        (Some(o), _) => forward(o),
        (None, Some(j)) => Ok(j),
        (None, None) => forward(&[]),
    }
}

/// How [`prepare`] reads a placement's samples.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Reading {
    /// The placement the samples belong to.
    pub placement: usize,
    /// Every sample needs joint readings and the rig an arm: the solver
    /// models the arm (encoder offsets, base or tool). Direct views are
    /// then kept as constraints on it; else they are left out.
    pub arm_modelled: bool,
    /// `J` from the joints through the rig's arm, never a sample's
    /// `jx,jy,jz` (which a corrected base or tool would make stale).
    pub from_joints: bool,
}

/// Checks and prepares one placement's samples: its mirror views, and its
/// direct views when the arm is modelled.
pub(crate) fn prepare(
    rig: &Rig,
    samples: &[Sample],
    reading: Reading,
) -> Result<Vec<Observation>, CalibrateError> {
    let mut out = Vec::new();
    let used = samples
        .iter()
        .filter(|s| s.view == View::Mirror || reading.arm_modelled);
    for s in used {
        let bad = |reason: String| CalibrateError::BadSample {
            pose: s.pose,
            reason,
        };
        if !s.pixels.iter().all(|p| p.iter().all(|v| v.is_finite())) {
            return Err(bad("non-finite pixel coordinates".into()));
        }
        if reading.arm_modelled {
            if rig.arm.is_none() {
                return Err(bad(
                    "encoder offsets, the base and the tool need the rig's [arm]".into(),
                ));
            }
            if s.joints.is_none() {
                return Err(bad(
                    "encoder offsets, the base and the tool need joint angles (q0..) in every sample"
                        .into(),
                ));
            }
        }
        let model_point = model_point(rig, s, reading.from_joints.then_some(&[][..]))?;
        if !model_point.iter().all(|v| v.is_finite()) {
            return Err(bad("non-finite end-effector position".into()));
        }
        let reflected_point = triangulate(rig.camera_refs(), s.pixels)
            .map_err(|e| bad(format!("cannot triangulate: {e}")))?;
        out.push(Observation {
            pose: s.pose,
            placement: reading.placement,
            view: s.view,
            model_point,
            joints: s.joints.clone(),
            reflected_point,
            pixels: s.pixels,
        });
    }
    check_mirror_samples(&out)?;
    Ok(out)
}

/// Fails unless the mirror views among `obs` are enough and spread enough
/// to determine a plane.
fn check_mirror_samples(obs: &[Observation]) -> Result<(), CalibrateError> {
    let points: Vec<Vector3<f64>> = obs
        .iter()
        .filter(|o| o.view == View::Mirror)
        .map(|o| o.model_point)
        .collect();
    if points.len() < MIN_SAMPLES {
        return Err(CalibrateError::TooFewSamples {
            found: points.len(),
        });
    }
    let mean = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
    let spread_mm = (points
        .iter()
        .map(|p| (p - mean).norm_squared())
        .sum::<f64>()
        / points.len() as f64)
        .sqrt();
    if spread_mm < MIN_SPREAD_MM {
        return Err(CalibrateError::PosesAlike { spread_mm });
    }
    Ok(())
}

/// The mirror plane halfway between the `J`s and the `Ĵ`s (paper Eqs 6-9),
/// in whatever frame the points are given; normal oriented from `Ĵ` to `J`
/// (towards the robot).
pub(crate) fn midplane(
    pairs: impl Iterator<Item = (Vector3<f64>, Vector3<f64>)> + Clone,
) -> Result<Plane, GeometryError> {
    let n = pairs.clone().count() as f64;
    // Eq 6: the normal is the mean vector from J to Ĵ.
    let normal = pairs.clone().map(|(j, jh)| jh - j).sum::<Vector3<f64>>() / n;
    // Eq 8: Π4 places the plane equidistant from both sets.
    let pi4 = -pairs
        .map(|(j, jh)| normal.dot(&jh) + normal.dot(&j))
        .sum::<f64>()
        / (2.0 * n);
    // Plane::new normalises; flip so the normal points back to the robot.
    Ok(Plane::new(normal, pi4)?.flipped())
}

/// Fails if a camera lies (nearly) in the plane.
pub(crate) fn check_plane_clear_of_cameras(rig: &Rig, plane: &Plane) -> Result<(), CalibrateError> {
    for (cam, name) in rig.cameras.iter().zip(&rig.names) {
        let distance_mm = plane.signed_distance(&cam.center).abs();
        // NaN distances fail too.
        if distance_mm.is_nan() || distance_mm < MIN_CAMERA_PLANE_DISTANCE_MM {
            return Err(CalibrateError::PlaneThroughCamera {
                camera: name.clone(),
                distance_mm,
            });
        }
    }
    Ok(())
}

/// Fails if the cameras see the plane edge-on: the median angle between the
/// rays to the reflections `Ĵ` and the plane is under [`MIN_GRAZING_DEG`].
pub(crate) fn check_plane_not_edge_on<'a>(
    rig: &Rig,
    plane: &Plane,
    obs: impl IntoIterator<Item = &'a Observation>,
) -> Result<(), CalibrateError> {
    let mut angles: Vec<f64> = obs
        .into_iter()
        .flat_map(|o| {
            rig.cameras.iter().map(move |c| {
                let ray = (o.reflected_point - c.center).normalize();
                plane
                    .normal
                    .dot(&ray)
                    .abs()
                    .clamp(0.0, 1.0)
                    .asin()
                    .to_degrees()
            })
        })
        .collect();
    angles.sort_by(f64::total_cmp);
    let grazing_deg = angles.get(angles.len() / 2).copied().unwrap_or(f64::NAN);
    // NaN fails too.
    if grazing_deg.is_nan() || grazing_deg < MIN_GRAZING_DEG {
        return Err(CalibrateError::MirrorEdgeOn { grazing_deg });
    }
    Ok(())
}

/// RMS over samples and cameras of the Euclidean reprojection error.
pub(crate) fn rms_px(residuals: &nalgebra::DVector<f64>) -> f64 {
    (residuals.norm_squared() / (residuals.len() as f64 / 2.0)).sqrt()
}

/// What [`calibrate_with`] does beyond one least-squares fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrateOptions {
    /// State the uncertainty (the covariance at the solution).
    pub uncertainty: bool,
    /// Find and set aside samples that do not fit the others.
    pub set_aside_outliers: bool,
    /// Judge the fit against the expected noise, and name a likely cause
    /// when it is poor.
    pub judge_fit: bool,
    /// The detections' noise, px per coordinate; else the rig's
    /// `pixel_sigma`, else [`TRACKER_PIXEL_SIGMA`].
    pub pixel_sigma: Option<f64>,
    /// Where the joint methods' refinement of a single placement starts:
    /// an earlier solution (a mirror calibrated again after it moved);
    /// else midway between the samples' J and Ĵ.
    pub start_plane: Option<Plane>,
}

impl Default for CalibrateOptions {
    fn default() -> Self {
        Self {
            uncertainty: true,
            set_aside_outliers: true,
            judge_fit: true,
            pixel_sigma: None,
            start_plane: None,
        }
    }
}

impl CalibrateOptions {
    /// Only the least-squares fit: no uncertainty, no outlier test, no
    /// judgement.
    pub fn plain() -> Self {
        Self {
            uncertainty: false,
            set_aside_outliers: false,
            judge_fit: false,
            pixel_sigma: None,
            start_plane: None,
        }
    }

    /// The noise the fit is judged against for `rig`.
    pub fn pixel_sigma_for(&self, rig: &Rig) -> f64 {
        self.pixel_sigma
            .or(rig.pixel_sigma)
            .unwrap_or(TRACKER_PIXEL_SIGMA)
    }
}

/// Calibrates the mirror cameras from `samples` (mirror views) with
/// `method`, stating the uncertainty and setting outliers aside.
pub fn calibrate(
    rig: &Rig,
    samples: &[Sample],
    method: Method,
) -> Result<Calibration, CalibrateError> {
    calibrate_with(rig, samples, method, CalibrateOptions::default())
}

/// Calibrates the mirror cameras of one mirror placement from `samples`
/// with `method` (see [`calibrate_placements`]).
pub fn calibrate_with(
    rig: &Rig,
    samples: &[Sample],
    method: Method,
    options: CalibrateOptions,
) -> Result<Calibration, CalibrateError> {
    calibrate_placements(rig, &[samples], method, Estimate::default(), options)
}

/// Calibrates from the samples of one or more mirror placements with
/// `method`: one plane per placement, the rig's cameras and one arm shared
/// by all, and with `estimate` the arm's base and tool too. Direct views
/// are constraints on the arm when it is modelled (encoder offsets, base
/// or tool), else left out.
///
/// Samples that do not fit the others are found and set aside: after a
/// least-squares fit on all of them, each sample's squared reprojection
/// error (both cameras, 4 coordinates) is compared with the noise scale
/// the samples show (their median, which half of them may exceed without
/// moving it); a sample beyond the 99.9% point of that noise is set aside
/// and the rest refitted, until the set stops changing. Every sample is
/// judged again against each new fit, so one set aside by a fit that the
/// outliers had pulled comes back. The final calibration is a plain
/// least-squares fit on the samples kept.
///
/// What the samples cannot determine is refused: the base from one
/// placement's mirror views alone (the plane trades off against it), and
/// any base or tool direction the fit's Jacobian leaves free.
pub fn calibrate_placements(
    rig: &Rig,
    placements: &[&[Sample]],
    method: Method,
    estimate: Estimate,
    options: CalibrateOptions,
) -> Result<Calibration, CalibrateError> {
    check_estimable(rig, placements, method, estimate)?;
    let reading = |placement| Reading {
        placement,
        arm_modelled: method == Method::JointKinematics || estimate.any(),
        from_joints: estimate.any(),
    };
    let mut obs = Vec::new();
    for (p, samples) in placements.iter().enumerate() {
        let prepared =
            prepare(rig, samples, reading(p)).map_err(|e| in_placement(e, p, placements.len()))?;
        obs.extend(prepared);
    }
    if estimate.base && placements.len() == 1 && obs.iter().all(|o| o.view == View::Mirror) {
        return Err(CalibrateError::CannotEstimate {
            what: "the arm's base".into(),
            why: "from one mirror placement with mirror views only, the mirror plane trades off against the base (the reflections fix only the two together); add direct views (view = direct rows) or the samples of two more placements".into(),
        });
    }
    let sigma = options.pixel_sigma_for(rig);
    let prior = options.uncertainty.then_some(sigma);
    let start = options.start_plane.filter(|_| placements.len() == 1);
    let solve =
        |obs: &[Observation]| solve(rig, obs, placements.len(), method, estimate, prior, start);
    let mut cal = solve(&obs)?;
    let mut kept = vec![true; obs.len()];
    // Each sample's error under `cal`, kept current with it.
    let mut errors = squared_errors(rig, &obs, &cal);
    // Whether the outlier test found more than a third inconsistent.
    let mut too_many_outliers = false;
    let rounds = if options.set_aside_outliers {
        MAX_REJECTION_ROUNDS
    } else {
        0
    };
    for _ in 0..rounds {
        let fitted = kept.iter().filter(|k| **k).count();
        let views: Vec<View> = obs.iter().map(|o| o.view).collect();
        let keep = consistent(&errors, &views, 4 * fitted, cal.parameters);
        let count = keep.iter().filter(|k| **k).count();
        // Setting aside more than a third is not outliers but a model that
        // does not fit (judged below), and too few left cannot be solved.
        too_many_outliers = count * 3 < 2 * obs.len();
        if keep == kept || count < MIN_SAMPLES || too_many_outliers {
            break;
        }
        let subset: Vec<Observation> = obs
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(o, _)| o.clone())
            .collect();
        // A subset that cannot be solved (seen edge-on, too few left in a
        // placement) leaves the last fit standing.
        match solve(&subset) {
            Ok(refit) => cal = refit,
            Err(e) => {
                tracing::debug!("outlier test stopped: refitting the samples kept failed: {e}");
                break;
            }
        }
        kept = keep;
        errors = squared_errors(rig, &obs, &cal);
    }
    let several = placements.len() > 1;
    cal.rejected = obs
        .iter()
        .zip(&kept)
        .zip(&errors)
        .filter(|((_, k), _)| !**k)
        .map(|((o, _), e)| RejectedSample {
            pose: o.pose,
            residual_px: (e / 2.0).sqrt(),
            placement: several.then_some(o.placement),
        })
        .collect();
    cal.fit = if options.judge_fit {
        let offset_model_fits = || {
            method == Method::Joint
                && calibrate_placements(
                    rig,
                    placements,
                    Method::JointKinematics,
                    estimate,
                    CalibrateOptions {
                        uncertainty: false,
                        pixel_sigma: Some(sigma),
                        ..CalibrateOptions::default()
                    },
                )
                .is_ok_and(|c| c.fit == Fit::Good)
        };
        judge(&cal, sigma, too_many_outliers, offset_model_fits)
    } else {
        Fit::NotJudged
    };
    Ok(cal)
}

/// Refuses, before any fit, what `method` or the rig cannot estimate.
fn check_estimable(
    rig: &Rig,
    placements: &[&[Sample]],
    method: Method,
    estimate: Estimate,
) -> Result<(), CalibrateError> {
    let what = || match (estimate.base, estimate.tool) {
        (true, true) => "the arm's base and tool",
        (true, false) => "the arm's base",
        _ => "the tool",
    };
    if placements.is_empty() {
        return Err(CalibrateError::TooFewSamples { found: 0 });
    }
    if method == Method::Paper && placements.len() > 1 {
        return Err(CalibrateError::CannotEstimate {
            what: "one calibration across several placements".into(),
            why: "the paper's method solves each mirror camera on its own; use --method joint or joint+kinematics".into(),
        });
    }
    if !estimate.any() {
        return Ok(());
    }
    if method == Method::Paper {
        return Err(CalibrateError::CannotEstimate {
            what: what().into(),
            why: "the paper's method has no arm model; use --method joint or joint+kinematics"
                .into(),
        });
    }
    if rig.arm.is_none() {
        return Err(CalibrateError::CannotEstimate {
            what: what().into(),
            why: "the rig has no [arm]".into(),
        });
    }
    Ok(())
}

/// `e` as an error of placement `p`, when there is more than one.
fn in_placement(e: CalibrateError, p: usize, placements: usize) -> CalibrateError {
    if placements > 1 {
        CalibrateError::InPlacement {
            placement: p,
            source: Box::new(e),
        }
    } else {
        e
    }
}

/// Whether `cal` fits its kept samples to the noise `sigma` explains: the
/// sum of squared residuals over `sigma^2` against the 99.9% point of
/// chi-square with (residuals - parameters) degrees of freedom. When it
/// does not, the likely cause, tried in turn: encoder offsets that `joint`
/// cannot model (then `joint+kinematics` fits: `offset_model_fits`),
/// samples from more than one mirror or rig (the outlier test found over a
/// third inconsistent, or the residuals are many times the noise), or
/// detections noisier than stated.
fn judge(
    cal: &Calibration,
    sigma: f64,
    too_many_outliers: bool,
    offset_model_fits: impl Fn() -> bool,
) -> Fit {
    let residuals = 4 * (cal.samples + cal.direct_samples);
    let chi2 = cal.train_rms_px.powi(2) * (residuals as f64 / 2.0) / (sigma * sigma);
    let limit = chi2_quantile_999(residuals.saturating_sub(cal.parameters).max(1));
    if chi2 <= limit {
        return Fit::Good;
    }
    let leaves = format!(
        "the fit leaves {:.2} px RMS where {sigma} px noise explains {:.2} px",
        cal.train_rms_px,
        sigma * 2f64.sqrt()
    );
    let cause = if offset_model_fits() {
        format!("{leaves}; joint readings look offset: use --method joint+kinematics")
    } else if too_many_outliers || chi2 > NOISIER_THAN_STATED.powi(2) * limit {
        format!(
            "{leaves}; the samples do not fit one mirror with this rig: did the mirror move, are two placements or wrong pairings mixed in, or is the rig's camera or arm wrong?"
        )
    } else {
        format!(
            "{leaves}; the detections look noisier than stated (--pixel-sigma, or pixel_sigma in the rig), or the rig is slightly off"
        )
    };
    Fit::Poor { cause }
}

/// How many times the noise's RMS a poor fit may leave and still be put
/// down to noisier detections than stated, rather than to samples that do
/// not fit one mirror.
const NOISIER_THAN_STATED: f64 = 5.0;

/// The 99.9% point of chi-square with `dof` degrees of freedom, by the
/// Wilson-Hilferty cube-root normal approximation (within 1% from 3 degrees
/// of freedom on, which is all a verdict needs).
fn chi2_quantile_999(dof: usize) -> f64 {
    const Z_999: f64 = 3.090_232;
    let k = dof as f64;
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + Z_999 * a.sqrt()).powi(3)
}

/// Most fits of the outlier test.
const MAX_REJECTION_ROUNDS: usize = 8;
/// The 99.9% point of chi-square with 4 degrees of freedom (a sample's two
/// pixels): a sample of pure noise exceeds it once in a thousand.
const CHI2_4_999: f64 = 18.467;
/// The median of chi-square with 4 degrees of freedom.
const CHI2_4_MEDIAN: f64 = 3.357;
/// Smallest noise scale the outlier test assumes, px: noiseless samples
/// are all consistent.
const MIN_NOISE_PX: f64 = 1e-3;

/// Each sample's squared reprojection error under `cal`, px^2 (both
/// cameras); infinite where the model point does not project.
fn squared_errors(rig: &Rig, obs: &[Observation], cal: &Calibration) -> Vec<f64> {
    let rig = cal.corrected_rig(rig);
    obs.iter()
        .map(|o| {
            let seen = Seen {
                placement: o.placement,
                view: o.view,
                joints: o.joints.as_deref(),
                model_point: Some(o.model_point),
                pixels: &o.pixels,
            };
            match camera_errors(cal, &rig, &seen) {
                Some([a, b]) if (a + b).is_finite() => a + b,
                _ => f64::INFINITY,
            }
        })
        .collect()
}

/// A sample as [`camera_errors`] scores it.
pub(crate) struct Seen<'a> {
    /// Its mirror placement.
    pub placement: usize,
    /// Seen in the mirror or directly.
    pub view: View,
    /// Its joint readings, if any.
    pub joints: Option<&'a [f64]>,
    /// Its end-effector model point `J`, if known without the arm.
    pub model_point: Option<Vector3<f64>>,
    /// Its detections, left then right.
    pub pixels: &'a [Vector2<f64>; 2],
}

/// The squared reprojection error (px^2) in each camera of `seen` under
/// `cal`, with `corrected` the rig as `cal` corrected it
/// ([`Calibration::corrected_rig`]): its marker point (from the arm where
/// `cal` models it, else its model point) through its placement's mirror
/// cameras, or the real cameras for a direct view. `None` where the point
/// is unknown or does not project.
pub(crate) fn camera_errors(
    cal: &Calibration,
    corrected: &Rig,
    seen: &Seen<'_>,
) -> Option<[f64; 2]> {
    let point = marker_point(cal, corrected, seen)?;
    let cameras = match seen.view {
        View::Mirror => &cal.placements.get(seen.placement)?.mirror_cameras,
        View::Direct => &corrected.cameras,
    };
    let error = |k: usize| -> Option<f64> {
        Some((cameras[k].project(&point).ok()? - seen.pixels[k]).norm_squared())
    };
    Some([error(0)?, error(1)?])
}

/// Where the marker of `seen` is under `cal` (`corrected` as in
/// [`camera_errors`]): from the arm where `cal` models it, else its model
/// point.
pub(crate) fn marker_point(
    cal: &Calibration,
    corrected: &Rig,
    seen: &Seen<'_>,
) -> Option<Vector3<f64>> {
    let arm = corrected.arm.as_ref().filter(|_| cal.uses_arm());
    match (arm, seen.joints) {
        (Some(arm), Some(q)) => arm
            .end_effector(q, cal.joint_offsets.as_deref().unwrap_or_default())
            .ok(),
        _ => seen.model_point,
    }
}

/// Which samples are consistent with the noise the samples show, from a fit
/// of `parameters` to `residuals` coordinates: fitted residuals are smaller
/// than the noise by `(m - p) / m` on average, which the scale undoes.
/// Mirror and direct views are each judged against their own kind's noise
/// where there are enough of them: a direct view is nearer and its marker
/// larger, and its detections are noisier (on renders, 0.2-0.4 px against
/// the mirror views' 0.08).
fn consistent(errors: &[f64], views: &[View], residuals: usize, parameters: usize) -> Vec<bool> {
    let median = |of: &dyn Fn(View) -> bool| {
        let mut sorted: Vec<f64> = errors
            .iter()
            .zip(views)
            .filter(|(_, v)| of(**v))
            .map(|(e, _)| *e)
            .collect();
        sorted.sort_by(f64::total_cmp);
        (sorted.len() >= OWN_NOISE_SCALE_FROM).then(|| sorted[sorted.len() / 2])
    };
    let Some(pooled) = median(&|_| true).or_else(|| {
        let mut all = errors.to_vec();
        all.sort_by(f64::total_cmp);
        all.get(all.len() / 2).copied()
    }) else {
        return Vec::new();
    };
    let shrink = residuals as f64 / residuals.saturating_sub(parameters).max(1) as f64;
    let bound = |median: f64| {
        CHI2_4_999 * (median / CHI2_4_MEDIAN * shrink).max(MIN_NOISE_PX * MIN_NOISE_PX)
    };
    let mirror = bound(median(&|v| v == View::Mirror).unwrap_or(pooled));
    let direct = bound(median(&|v| v == View::Direct).unwrap_or(pooled));
    errors
        .iter()
        .zip(views)
        .map(|(e, v)| match v {
            View::Mirror => *e <= mirror,
            View::Direct => *e <= direct,
        })
        .collect()
}

/// Fewest samples of one view kind whose median sets that kind's noise
/// scale in the outlier test.
const OWN_NOISE_SCALE_FROM: usize = 5;

/// One least-squares calibration of `obs` (from `placements` placements)
/// with `method`, checked.
fn solve(
    rig: &Rig,
    obs: &[Observation],
    placements: usize,
    method: Method,
    estimate: Estimate,
    prior_sigma: Option<f64>,
    start_plane: Option<Plane>,
) -> Result<Calibration, CalibrateError> {
    // Each placement's J/Ĵ midplane: the joint methods start from it (or
    // from `start_plane`, checked the same), and the paper's per-camera
    // planes are it in each camera's frame.
    let mut starts = Vec::with_capacity(placements);
    for p in 0..placements {
        let mirrored: Vec<&Observation> = obs
            .iter()
            .filter(|o| o.placement == p && o.view == View::Mirror)
            .collect();
        let start = (|| {
            if mirrored.len() < MIN_SAMPLES {
                return Err(CalibrateError::TooFewSamples {
                    found: mirrored.len(),
                });
            }
            let start = match start_plane {
                Some(plane) => plane,
                None => midplane(mirrored.iter().map(|o| (o.model_point, o.reflected_point)))?,
            };
            check_plane_clear_of_cameras(rig, &start)?;
            check_plane_not_edge_on(rig, &start, mirrored.iter().copied())?;
            Ok(start)
        })()
        .map_err(|e| in_placement(e, p, placements))?;
        starts.push(start);
    }
    let cal = match method {
        Method::Paper => paper::calibrate(rig, obs, prior_sigma)?,
        Method::Joint => joint::calibrate(rig, obs, &starts, false, estimate, prior_sigma)?,
        Method::JointKinematics => {
            joint::calibrate(rig, obs, &starts, true, estimate, prior_sigma)?
        }
    };
    let finite = cal.placements.iter().all(|p| {
        p.mirror_cameras.iter().all(|c| {
            c.camera_from_world
                .iter()
                .chain(c.center.iter())
                .all(|v| v.is_finite())
        })
    }) && cal.train_rms_px.is_finite();
    if !finite {
        return Err(GeometryError::NonFinite("calibration result").into());
    }
    for (p, placement) in cal.placements.iter().enumerate() {
        if let Some(plane) = &placement.plane {
            let mirrored = obs
                .iter()
                .filter(|o| o.placement == p && o.view == View::Mirror);
            check_plane_clear_of_cameras(rig, plane)
                .and_then(|()| check_plane_not_edge_on(rig, plane, mirrored))
                .map_err(|e| in_placement(e, p, placements))?;
        }
    }
    Ok(cal)
}
