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

mod joint;
mod paper;
pub mod uncertainty;

pub use paper::initial_estimate as paper_initial_estimate;
pub use uncertainty::Uncertainty;

use geometry::{Camera, GeometryError, Plane, Rig, Sample, View, triangulate::triangulate};
use nalgebra::{Vector2, Vector3};

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
    /// Mirror samples used.
    pub samples: usize,
    /// What the solved values are known to.
    pub uncertainty: Uncertainty,
    /// Samples set aside as not fitting the others (a wrong pairing, a
    /// misread marker), with their residuals under this calibration.
    pub rejected: Vec<RejectedSample>,
    /// Whether the samples kept fit the model to the expected noise.
    pub fit: Fit,
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
    }
}

/// One mirror sample prepared for a solver.
#[derive(Debug, Clone)]
pub(crate) struct Observation {
    /// Its pose id.
    pub pose: u64,
    /// The end-effector model's prediction `J` (no offsets).
    pub model_point: Vector3<f64>,
    /// Joint readings, when known.
    pub joints: Option<Vec<f64>>,
    /// `Ĵ`: the reflection triangulated through the real cameras.
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

/// Checks and prepares the mirror samples (direct ones are ignored).
pub(crate) fn prepare(
    rig: &Rig,
    samples: &[Sample],
    need_joints: bool,
) -> Result<Vec<Observation>, CalibrateError> {
    let mut out = Vec::new();
    for s in samples.iter().filter(|s| s.view == View::Mirror) {
        let bad = |reason: String| CalibrateError::BadSample {
            pose: s.pose,
            reason,
        };
        if !s.pixels.iter().all(|p| p.iter().all(|v| v.is_finite())) {
            return Err(bad("non-finite pixel coordinates".into()));
        }
        if need_joints {
            if rig.arm.is_none() {
                return Err(bad("joint offsets need the rig's [arm]".into()));
            }
            if s.joints.is_none() {
                return Err(bad(
                    "joint offsets need joint angles (q0..) in every sample".into(),
                ));
            }
        }
        let model_point = model_point(rig, s, None)?;
        if !model_point.iter().all(|v| v.is_finite()) {
            return Err(bad("non-finite end-effector position".into()));
        }
        let reflected_point = triangulate(rig.camera_refs(), s.pixels)
            .map_err(|e| bad(format!("cannot triangulate: {e}")))?;
        out.push(Observation {
            pose: s.pose,
            model_point,
            joints: s.joints.clone(),
            reflected_point,
            pixels: s.pixels,
        });
    }
    if out.len() < MIN_SAMPLES {
        return Err(CalibrateError::TooFewSamples { found: out.len() });
    }
    let mean = out.iter().map(|o| o.model_point).sum::<Vector3<f64>>() / out.len() as f64;
    let spread_mm = (out
        .iter()
        .map(|o| (o.model_point - mean).norm_squared())
        .sum::<f64>()
        / out.len() as f64)
        .sqrt();
    if spread_mm < MIN_SPREAD_MM {
        return Err(CalibrateError::PosesAlike { spread_mm });
    }
    Ok(out)
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
pub(crate) fn check_plane_not_edge_on(
    rig: &Rig,
    plane: &Plane,
    obs: &[Observation],
) -> Result<(), CalibrateError> {
    let mut angles: Vec<f64> = obs
        .iter()
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
}

impl Default for CalibrateOptions {
    fn default() -> Self {
        Self {
            uncertainty: true,
            set_aside_outliers: true,
            judge_fit: true,
            pixel_sigma: None,
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

/// Calibrates the mirror cameras from `samples` (mirror views) with `method`.
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
pub fn calibrate_with(
    rig: &Rig,
    samples: &[Sample],
    method: Method,
    options: CalibrateOptions,
) -> Result<Calibration, CalibrateError> {
    let obs = prepare(rig, samples, method == Method::JointKinematics)?;
    let sigma = options.pixel_sigma_for(rig);
    let prior = options.uncertainty.then_some(sigma);
    let solve = |obs: &[Observation]| solve(rig, obs, method, prior);
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
        let keep = consistent(&errors, 4 * fitted, parameters(rig, method));
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
        // A subset that cannot be solved (seen edge-on, say) leaves the
        // last fit standing.
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
    cal.rejected = obs
        .iter()
        .zip(&kept)
        .zip(&errors)
        .filter(|((_, k), _)| !**k)
        .map(|((o, _), e)| RejectedSample {
            pose: o.pose,
            residual_px: (e / 2.0).sqrt(),
        })
        .collect();
    cal.fit = if options.judge_fit {
        judge(rig, samples, method, &cal, sigma, too_many_outliers)
    } else {
        Fit::NotJudged
    };
    Ok(cal)
}

/// Whether `cal` fits its kept samples to the noise `sigma` explains: the
/// sum of squared residuals over `sigma^2` against the 99.9% point of
/// chi-square with (residuals - parameters) degrees of freedom. When it
/// does not, the likely cause, tried in turn: encoder offsets that `joint`
/// cannot model (then `joint+kinematics` fits), samples from more than one
/// mirror or rig (the outlier test found over a third inconsistent, or the
/// residuals are many times the noise), or detections noisier than stated.
fn judge(
    rig: &Rig,
    samples: &[Sample],
    method: Method,
    cal: &Calibration,
    sigma: f64,
    too_many_outliers: bool,
) -> Fit {
    let residuals = 4 * cal.samples;
    let p = parameters(rig, method);
    let chi2 = cal.train_rms_px.powi(2) * (residuals as f64 / 2.0) / (sigma * sigma);
    let limit = chi2_quantile_999(residuals.saturating_sub(p).max(1));
    if chi2 <= limit {
        return Fit::Good;
    }
    let leaves = format!(
        "the fit leaves {:.2} px RMS where {sigma} px noise explains {:.2} px",
        cal.train_rms_px,
        sigma * 2f64.sqrt()
    );
    let offset_model_fits = method == Method::Joint
        && rig.arm.is_some()
        && samples
            .iter()
            .all(|s| s.view != View::Mirror || s.joints.is_some())
        && calibrate_with(
            rig,
            samples,
            Method::JointKinematics,
            CalibrateOptions {
                uncertainty: false,
                pixel_sigma: Some(sigma),
                ..CalibrateOptions::default()
            },
        )
        .is_ok_and(|c| c.fit == Fit::Good);
    let cause = if offset_model_fits {
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
    obs.iter()
        .map(|o| {
            let point = match (&cal.joint_offsets, &rig.arm, &o.joints) {
                (Some(offsets), Some(arm), Some(q)) => arm.end_effector(q, offsets).ok(),
                _ => Some(o.model_point),
            };
            let error = |k: usize| {
                let p = point?;
                Some((cal.mirror_cameras[k].project(&p).ok()? - o.pixels[k]).norm_squared())
            };
            match (error(0), error(1)) {
                (Some(a), Some(b)) if (a + b).is_finite() => a + b,
                _ => f64::INFINITY,
            }
        })
        .collect()
}

/// Parameters `method` solves for.
fn parameters(rig: &Rig, method: Method) -> usize {
    match method {
        Method::Paper => 12,
        Method::Joint => 3,
        Method::JointKinematics => 3 + rig.arm.as_ref().map_or(0, |a| a.dof()),
    }
}

/// Which samples are consistent with the noise the samples show, from a fit
/// of `parameters` to `residuals` coordinates: fitted residuals are smaller
/// than the noise by `(m - p) / m` on average, which the scale undoes.
fn consistent(errors: &[f64], residuals: usize, parameters: usize) -> Vec<bool> {
    let mut sorted = errors.to_vec();
    sorted.sort_by(f64::total_cmp);
    let Some(&median) = sorted.get(sorted.len() / 2) else {
        return Vec::new();
    };
    let shrink = residuals as f64 / residuals.saturating_sub(parameters).max(1) as f64;
    let sigma_squared = (median / CHI2_4_MEDIAN * shrink).max(MIN_NOISE_PX * MIN_NOISE_PX);
    errors
        .iter()
        .map(|e| *e <= CHI2_4_999 * sigma_squared)
        .collect()
}

/// One least-squares calibration of `obs` with `method`, checked.
fn solve(
    rig: &Rig,
    obs: &[Observation],
    method: Method,
    prior_sigma: Option<f64>,
) -> Result<Calibration, CalibrateError> {
    // The J/Ĵ midplane: the joint methods start from it, and the paper's
    // per-camera planes are it in each camera's frame.
    let start = midplane(obs.iter().map(|o| (o.model_point, o.reflected_point)))?;
    check_plane_clear_of_cameras(rig, &start)?;
    check_plane_not_edge_on(rig, &start, obs)?;
    let cal = match method {
        Method::Paper => paper::calibrate(rig, obs, prior_sigma)?,
        Method::Joint => joint::calibrate(rig, obs, start, false, prior_sigma)?,
        Method::JointKinematics => joint::calibrate(rig, obs, start, true, prior_sigma)?,
    };
    let finite = cal.mirror_cameras.iter().all(|c| {
        c.camera_from_world
            .iter()
            .chain(c.center.iter())
            .all(|v| v.is_finite())
    }) && cal.train_rms_px.is_finite();
    if !finite {
        return Err(GeometryError::NonFinite("calibration result").into());
    }
    if let Some(plane) = &cal.plane {
        check_plane_clear_of_cameras(rig, plane)?;
        check_plane_not_edge_on(rig, plane, obs)?;
    }
    Ok(cal)
}
