//! Mirror planes shared by both cameras, optionally with encoder offsets and
//! the arm's base and tool.
//!
//! Parameters ([`Layout`]): per mirror placement the plane's normal as a 2-D
//! step in the tangent plane of its initial normal and its offset `d`; then
//! (with kinematics) the encoder offsets; then (when estimated) a correction
//! of the arm's base, `world_from_base * exp(w, t)` (rotation vector `w`,
//! translation `t`, in the base's frame); then a shift of the tool point.
//! Residuals: each mirror sample's end-effector point, reflected in its
//! placement's plane and projected through each real camera, against the
//! detections (the same as projecting it through the mirror cameras the
//! plane implies); each direct sample's point projected as it is.

use std::borrow::Cow;

use geometry::{Arm, Camera, GeometryError, Plane, Rig, View, lsq};
use nalgebra::{DVector, Isometry3, Vector3};

use super::uncertainty::{PlaneSigma, Uncertainty, chart, propagate_to_cameras};
use super::{
    CalibrateError, Calibration, Estimate, Method, Observation, PlacementFit,
    check_plane_clear_of_cameras, rms_px,
};

/// The plane's parameters: a step `(x0, x1)` in the tangent plane of `n0`
/// (radians, to first order, at zero), then the offset `d`.
struct PlaneChart {
    n0: Vector3<f64>,
    t1: Vector3<f64>,
    t2: Vector3<f64>,
}

impl PlaneChart {
    fn at(n0: Vector3<f64>) -> Self {
        let helper = if n0.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let t1 = n0.cross(&helper).normalize();
        let t2 = n0.cross(&t1);
        Self { n0, t1, t2 }
    }

    fn plane(&self, x: &[f64]) -> Result<Plane, GeometryError> {
        Plane::new(self.n0 + self.t1 * x[0] + self.t2 * x[1], x[2])
    }
}

/// Where each estimated quantity sits in the parameter vector.
pub(super) struct Layout {
    /// Mirror placements, one plane each.
    placements: usize,
    /// The arm's joints.
    dof: usize,
    /// Whether encoder offsets are modelled at all.
    kinematics: bool,
    /// The joints whose offsets are estimated: all with kinematics, but
    /// for the first when the base is estimated (a turn of the base about
    /// the first joint's axis is that joint's offset) and the last when the
    /// tool is (a turn of the last joint moves the tool point as a tool
    /// shift does).
    free_offsets: Vec<usize>,
    estimate: Estimate,
}

impl Layout {
    pub(super) fn new(rig: &Rig, placements: usize, kinematics: bool, estimate: Estimate) -> Self {
        let dof = rig.arm.as_ref().map_or(0, Arm::dof);
        let free_offsets = if kinematics {
            (0..dof)
                .filter(|&j| {
                    let first_with_base = estimate.base && j == 0;
                    let last_with_tool = estimate.tool && j + 1 == dof;
                    !(first_with_base || last_with_tool)
                })
                .collect()
        } else {
            Vec::new()
        };
        Self {
            placements,
            dof,
            kinematics,
            free_offsets,
            estimate,
        }
    }

    /// Parameters in all.
    pub(super) fn len(&self) -> usize {
        self.tool_at() + if self.estimate.tool { 3 } else { 0 }
    }

    fn offsets_at(&self) -> usize {
        3 * self.placements
    }

    fn base_at(&self) -> usize {
        self.offsets_at() + self.free_offsets.len()
    }

    fn tool_at(&self) -> usize {
        self.base_at() + if self.estimate.base { 6 } else { 0 }
    }

    /// Whether the end-effector point comes from the arm's forward
    /// kinematics (else it is each sample's model point).
    fn uses_arm(&self) -> bool {
        !self.free_offsets.is_empty() || self.estimate.any()
    }

    /// Every joint's offset at `x` (zero where not estimated); empty
    /// without kinematics.
    fn offsets(&self, x: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; if self.kinematics { self.dof } else { 0 }];
        for (i, &j) in self.free_offsets.iter().enumerate() {
            out[j] = x[self.offsets_at() + i];
        }
        out
    }

    /// `arm` with the base and tool corrections of `x`.
    fn arm_at<'a>(&self, arm: &'a Arm, x: &[f64]) -> Cow<'a, Arm> {
        if !self.estimate.any() {
            return Cow::Borrowed(arm);
        }
        let mut arm = arm.clone();
        if self.estimate.base {
            let b = self.base_at();
            let w = Vector3::new(x[b], x[b + 1], x[b + 2]);
            let t = Vector3::new(x[b + 3], x[b + 4], x[b + 5]);
            arm.world_from_base *= Isometry3::new(t, w);
        }
        if self.estimate.tool {
            let t = self.tool_at();
            arm.tool += Vector3::new(x[t], x[t + 1], x[t + 2]);
        }
        Cow::Owned(arm)
    }

    /// What parameter `i` is, for a message.
    fn name(&self, i: usize, rig: &Rig) -> String {
        let placement = |p: usize| {
            if self.placements > 1 {
                format!(" (placement {p})")
            } else {
                String::new()
            }
        };
        if i < self.offsets_at() {
            let what = if i % 3 == 2 { "distance" } else { "tilt" };
            return format!("the mirror's {what}{}", placement(i / 3));
        }
        if i < self.base_at() {
            let j = self.free_offsets[i - self.offsets_at()];
            let names = rig.arm.as_ref().map(Arm::joint_names).unwrap_or_default();
            return format!(
                "the encoder offset of {}",
                names
                    .get(j)
                    .map_or_else(|| format!("joint {}", j + 1), Clone::clone)
            );
        }
        if i < self.tool_at() {
            return if i - self.base_at() < 3 {
                "the arm's base rotation".into()
            } else {
                "the arm's base position".into()
            };
        }
        "the tool (marker) position".into()
    }

    /// Whether parameter `i` is part of the base or the tool.
    fn is_base_or_tool(&self, i: usize) -> bool {
        i >= self.base_at()
    }
}

/// A chart centred on each of `planes`, and the parameter vector of
/// `layout` that puts every plane where it is (zero tilts, its distance;
/// everything else zero).
fn charts_at(planes: &[Plane], layout: &Layout) -> (Vec<PlaneChart>, DVector<f64>) {
    let charts = planes
        .iter()
        .map(|p| PlaneChart::at(p.normal.into_inner()))
        .collect();
    let mut x = DVector::zeros(layout.len());
    for (p, plane) in planes.iter().enumerate() {
        x[3 * p + 2] = plane.distance;
    }
    (charts, x)
}

/// The planes at `x`, one per placement.
fn planes(charts: &[PlaneChart], x: &[f64]) -> Result<Vec<Plane>, GeometryError> {
    charts
        .iter()
        .enumerate()
        .map(|(p, c)| c.plane(&x[3 * p..3 * p + 3]))
        .collect()
}

/// The residuals of parameters `x`: per sample and camera, the projection
/// of the end-effector point (reflected in its placement's plane for a
/// mirror view) minus the detection.
fn residuals(
    rig: &Rig,
    obs: &[Observation],
    charts: &[PlaneChart],
    layout: &Layout,
    x: &DVector<f64>,
) -> Option<DVector<f64>> {
    let x = x.as_slice();
    let planes = planes(charts, x).ok()?;
    let offsets = layout.offsets(x);
    let arm = if layout.uses_arm() {
        Some(layout.arm_at(rig.arm.as_ref()?, x))
    } else {
        None
    };
    let mut r = DVector::zeros(4 * obs.len());
    for (i, o) in obs.iter().enumerate() {
        let point = match &arm {
            None => o.model_point,
            Some(arm) => arm.end_effector(o.joints.as_ref()?, &offsets).ok()?,
        };
        let seen = match o.view {
            View::Mirror => planes[o.placement].reflect_point(&point),
            View::Direct => point,
        };
        for k in 0..2 {
            let d = rig.cameras[k].project(&seen).ok()? - o.pixels[k];
            r[4 * i + 2 * k] = d.x;
            r[4 * i + 2 * k + 1] = d.y;
        }
    }
    Some(r)
}

/// Refines from `starts`, each placement's plane midway between its J's and
/// Ĵ's. `prior_sigma`: state the uncertainty, with this pixel noise where
/// the residuals have no redundancy.
pub(super) fn calibrate(
    rig: &Rig,
    obs: &[Observation],
    starts: &[Plane],
    with_kinematics: bool,
    estimate: Estimate,
    prior_sigma: Option<f64>,
) -> Result<Calibration, CalibrateError> {
    let layout = Layout::new(rig, starts.len(), with_kinematics, estimate);
    let (start_charts, x0) = charts_at(starts, &layout);
    let (x, _) = lsq::minimize(x0, |x| residuals(rig, obs, &start_charts, &layout, x))?;
    let solved = planes(&start_charts, x.as_slice())?;
    for plane in &solved {
        check_plane_clear_of_cameras(rig, plane)?;
    }
    let r = residuals(rig, obs, &start_charts, &layout, &x)
        .ok_or(GeometryError::NonFinite("joint refinement residuals"))?;
    let joint_offsets = with_kinematics.then(|| layout.offsets(x.as_slice()));
    // The rig as solved: the base and tool corrections applied, so that
    // the covariance is taken in a chart centred on them.
    let mut solved_rig = rig.clone();
    if estimate.any()
        && let Some(arm) = solved_rig.arm.as_mut()
    {
        *arm = layout.arm_at(arm, x.as_slice()).into_owned();
    }
    // The base and tool are refused when not determined, so their
    // covariance is needed even when the uncertainty is not asked for.
    let uncertainty = match (prior_sigma, estimate.any()) {
        (None, false) => Uncertainty::not_stated("not asked for"),
        (prior, _) => {
            let stated = uncertainty(
                &solved_rig,
                obs,
                &solved,
                joint_offsets.as_deref(),
                &layout,
                &r,
                prior.unwrap_or(super::TRACKER_PIXEL_SIGMA),
            );
            if let Err(refusal @ CalibrateError::CannotEstimate { .. }) = stated {
                return Err(refusal);
            }
            match (prior, stated) {
                (None, _) => Uncertainty::not_stated("not asked for"),
                (Some(_), Ok(u)) => u,
                // A fit whose covariance cannot be formed is still a fit:
                // it says so.
                (Some(_), Err(e)) => Uncertainty::not_stated(&e.to_string()),
            }
        }
    };
    let arm = solved_rig.arm.as_ref();
    let mirror_samples = |p: usize| {
        obs.iter()
            .filter(|o| o.view == View::Mirror && o.placement == p)
            .count()
    };
    let placements: Vec<PlacementFit> = solved
        .iter()
        .enumerate()
        .map(|(p, plane)| PlacementFit {
            plane: Some(*plane),
            mirror_cameras: mirror_cameras(rig, plane),
            samples: mirror_samples(p),
        })
        .collect();
    Ok(Calibration {
        method: if with_kinematics {
            Method::JointKinematics
        } else {
            Method::Joint
        },
        plane: Some(solved[0]),
        mirror_cameras: mirror_cameras(rig, &solved[0]),
        joint_offsets,
        initial_cameras: mirror_cameras(rig, &starts[0]),
        train_rms_px: rms_px(&r),
        samples: obs.iter().filter(|o| o.view == View::Mirror).count(),
        direct_samples: obs.iter().filter(|o| o.view == View::Direct).count(),
        placements,
        world_from_base: arm.filter(|_| estimate.base).map(|a| a.world_from_base),
        tool: arm.filter(|_| estimate.tool).map(|a| a.tool),
        parameters: layout.len(),
        uncertainty,
        rejected: Vec::new(),
        fit: super::Fit::NotJudged,
    })
}

/// Both mirror cameras that `plane` makes of the rig's cameras.
fn mirror_cameras(rig: &Rig, plane: &Plane) -> [Camera; 2] {
    rig.cameras.map(|c| plane.mirror_camera(&c))
}

/// The covariance at the solution, in charts centred on the solved normals
/// (so that each plane's first two parameters are its tilt in radians) and
/// on the solved base and tool (`rig` is the rig as solved);
/// `solved_residuals` are the fit's residuals there, and `prior_sigma` the
/// pixel noise assumed where they have no redundancy to measure it. Fails
/// with [`CalibrateError::CannotEstimate`] when the base or the tool is
/// not determined.
fn uncertainty(
    rig: &Rig,
    obs: &[Observation],
    planes: &[Plane],
    offsets: Option<&[f64]>,
    layout: &Layout,
    solved_residuals: &DVector<f64>,
    prior_sigma: f64,
) -> Result<Uncertainty, CalibrateError> {
    let (charts_here, mut y) = charts_at(planes, layout);
    let offsets = offsets.unwrap_or_default();
    for (i, &j) in layout.free_offsets.iter().enumerate() {
        y[layout.offsets_at() + i] = offsets[j];
    }
    let at = |y: &DVector<f64>| residuals(rig, obs, &charts_here, layout, y);
    let undefined = || GeometryError::NonFinite("the fit's Jacobian at the solution");
    let jac = lsq::jacobian(&y, at).ok_or_else(undefined)?;
    let cov = lsq::covariance(&jac, solved_residuals, prior_sigma.powi(2))?;
    let names = |indices: &mut dyn Iterator<Item = usize>| {
        let mut out: Vec<String> = indices.map(|i| layout.name(i, rig)).collect();
        out.dedup();
        out
    };
    let unknown_arm = names(
        &mut cov
            .undetermined
            .iter()
            .copied()
            .filter(|&i| layout.is_base_or_tool(i)),
    );
    if !unknown_arm.is_empty() {
        let others = names(
            &mut cov
                .undetermined
                .iter()
                .copied()
                .filter(|&i| !layout.is_base_or_tool(i)),
        );
        let why = if others.is_empty() {
            "the samples do not determine it".to_string()
        } else {
            format!("it trades off against {}", others.join(", "))
        };
        return Err(CalibrateError::CannotEstimate {
            what: unknown_arm.join(", "),
            why: format!("{why}; add direct views or mirror placements, or estimate less"),
        });
    }
    let solved = mirror_cameras(rig, &planes[0]);
    let cameras = propagate_to_cameras(
        &cov,
        &[0.0, 0.0, planes[0].distance],
        &[1e-6, 1e-6, 1e-6 * (1.0 + planes[0].distance.abs())],
        |p| {
            let moved = charts_here[0].plane(p).ok()?;
            Some(chart(&solved, &mirror_cameras(rig, &moved)))
        },
    )
    .ok_or_else(undefined)?;
    let mut out = Uncertainty::from_cameras(cameras, cov.residual_variance);
    out.cameras_stated = !cov.undetermined.iter().any(|&i| i < 3);
    let plane_sigma = |p: usize| PlaneSigma {
        angle_deg: match (cov.sigma(3 * p), cov.sigma(3 * p + 1)) {
            (Some(a), Some(b)) => Some(a.hypot(b).to_degrees()),
            _ => None,
        },
        distance_mm: cov.sigma(3 * p + 2),
    };
    let first = plane_sigma(0);
    out.plane_angle_deg = first.angle_deg;
    out.plane_distance_mm = first.distance_mm;
    if layout.placements > 1 {
        out.placements = (0..layout.placements).map(plane_sigma).collect();
    }
    if layout.kinematics {
        // Revolute offsets in degrees; a prismatic joint's stays in mm.
        // An offset not estimated (part of the base or tool) has none.
        let kinds = rig.arm.as_ref().map(Arm::joint_kinds);
        let mut sigmas = vec![None; layout.dof];
        for (i, &j) in layout.free_offsets.iter().enumerate() {
            let prismatic =
                kinds.as_ref().and_then(|k| k.get(j)) == Some(&geometry::JointKind::Prismatic);
            sigmas[j] = cov
                .sigma(layout.offsets_at() + i)
                .map(|v| if prismatic { v } else { v.to_degrees() });
        }
        out.joint_offsets_deg = Some(sigmas);
    }
    // A 3-vector's 1-sigma: the RMS length of its error, sqrt(trace).
    let rms = |at: usize| {
        (0..3)
            .map(|i| cov.matrix[(at + i, at + i)].max(0.0))
            .sum::<f64>()
            .sqrt()
    };
    if layout.estimate.base {
        out.base_rotation_deg = Some(rms(layout.base_at()).to_degrees());
        out.base_translation_mm = Some(rms(layout.base_at() + 3));
    }
    if layout.estimate.tool {
        out.tool_mm = Some(rms(layout.tool_at()));
    }
    out.undetermined = names(&mut cov.undetermined.iter().copied());
    Ok(out)
}
