//! What a calibration is known to: the Gauss-Newton covariance of the solved
//! parameters (scaled by the fit's residual variance), summarised as 1-sigma
//! values, and carried over to the mirror cameras and to points located
//! through them.
//!
//! Every method's covariance is brought into one chart of the two mirror
//! cameras, so that whatever uses them (located objects, the live view)
//! does not need to know how they were solved: per camera a rotation vector
//! `w` (rad) applied on the camera side, `R' = exp(w) R`, and a shift of the
//! centre (mm), left camera first.

use geometry::{Camera, Plane, lsq::Covariance};
use nalgebra::{DMatrix, Matrix3, Rotation3, SMatrix, SVector, Vector3};

/// Parameters of the two mirror cameras' chart.
pub const CAMERA_PARAMS: usize = 12;
/// A perturbation of both mirror cameras in their chart.
pub type CameraDelta = SVector<f64, CAMERA_PARAMS>;
/// The covariance of both mirror cameras in their chart.
pub type CameraCovariance = SMatrix<f64, CAMERA_PARAMS, CAMERA_PARAMS>;

/// Camera `k`'s part of a chart vector: rotation vector, centre shift.
fn part(delta: &[f64], k: usize) -> (Vector3<f64>, Vector3<f64>) {
    let o = 6 * k;
    (
        Vector3::new(delta[o], delta[o + 1], delta[o + 2]),
        Vector3::new(delta[o + 3], delta[o + 4], delta[o + 5]),
    )
}

/// One camera moved by `delta` (rotation vector, centre shift) in the chart.
pub fn perturb_camera(camera: &Camera, delta: &[f64]) -> Camera {
    let (w, c) = part(delta, 0);
    Camera::new(
        camera.intrinsics,
        Rotation3::new(w).matrix() * camera.camera_from_world,
        camera.center + c,
    )
}

/// `cameras` moved by `delta`.
pub fn perturb(cameras: &[Camera; 2], delta: &CameraDelta) -> [Camera; 2] {
    [
        perturb_camera(&cameras[0], &delta.as_slice()[..6]),
        perturb_camera(&cameras[1], &delta.as_slice()[6..]),
    ]
}

/// Where `moved` lies in the chart around `base`: the inverse of [`perturb`].
pub fn chart(base: &[Camera; 2], moved: &[Camera; 2]) -> CameraDelta {
    let mut delta = CameraDelta::zeros();
    for k in 0..2 {
        let turn = moved[k].camera_from_world * base[k].camera_from_world.transpose();
        let w = Rotation3::from_matrix(&turn).scaled_axis();
        let c = moved[k].center - base[k].center;
        delta.fixed_rows_mut::<3>(6 * k).copy_from(&w);
        delta.fixed_rows_mut::<3>(6 * k + 3).copy_from(&c);
    }
    delta
}

/// A calibration's stated uncertainty, each a 1-sigma value.
#[derive(Debug, Clone, PartialEq)]
pub struct Uncertainty {
    /// False when no covariance could be formed at all (then every sigma
    /// is absent and `undetermined` says why).
    pub stated: bool,
    /// The fit's residual standard deviation per pixel coordinate, px: the
    /// tracker's noise as the fit sees it.
    pub residual_px: f64,
    /// RMS angle between the true and the estimated mirror normal, deg
    /// (`sqrt(E[angle^2])` over both tilt directions).
    pub plane_angle_deg: Option<f64>,
    /// The plane offset `d`, mm.
    pub plane_distance_mm: Option<f64>,
    /// Each encoder offset, deg; `None` for an offset the data do not determine.
    pub joint_offsets_deg: Option<Vec<Option<f64>>>,
    /// RMS distance between the true and the estimated mirror camera centre
    /// (`sqrt` of the trace of its covariance), mm, left then right.
    pub mirror_camera_centers_mm: [f64; 2],
    /// RMS rotation angle between the true and the estimated mirror camera
    /// orientation, deg, left then right.
    pub mirror_camera_angles_deg: [f64; 2],
    /// What the samples do not determine, named.
    pub undetermined: Vec<String>,
    /// Both mirror cameras' covariance in the chart of this module;
    /// meaningful only if `cameras_stated`.
    pub cameras: CameraCovariance,
    /// Whether the mirror cameras' covariance is stated: false when what
    /// they depend on is not determined, or no covariance could be formed.
    pub cameras_stated: bool,
    /// Each placement's plane, when calibrated across more than one (the
    /// first is also `plane_angle_deg` and `plane_distance_mm`).
    pub placements: Vec<PlaneSigma>,
    /// RMS rotation angle between the true and the estimated arm base,
    /// deg, when the base is estimated.
    pub base_rotation_deg: Option<f64>,
    /// RMS distance between the true and the estimated base origin, mm.
    pub base_translation_mm: Option<f64>,
    /// RMS distance between the true and the estimated tool point, mm,
    /// when the tool is estimated.
    pub tool_mm: Option<f64>,
}

/// One mirror plane's 1-sigma values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneSigma {
    /// RMS angle between the true and the estimated normal, deg.
    pub angle_deg: Option<f64>,
    /// The plane offset `d`, mm.
    pub distance_mm: Option<f64>,
}

impl Uncertainty {
    /// The summary of a camera-chart covariance, with the plane and joint
    /// parts left empty for the caller to fill.
    pub(crate) fn from_cameras(cameras: CameraCovariance, residual_variance: f64) -> Self {
        let (centers, angles) = camera_sigmas(&cameras);
        Self {
            stated: true,
            residual_px: residual_variance.max(0.0).sqrt(),
            plane_angle_deg: None,
            plane_distance_mm: None,
            joint_offsets_deg: None,
            mirror_camera_centers_mm: centers,
            mirror_camera_angles_deg: angles,
            undetermined: Vec::new(),
            cameras,
            cameras_stated: true,
            placements: Vec::new(),
            base_rotation_deg: None,
            base_translation_mm: None,
            tool_mm: None,
        }
    }

    /// No uncertainty could be formed, for `reason`: every sigma is absent
    /// (the cameras' zero and not stated) and `undetermined` says why.
    pub(crate) fn not_stated(reason: &str) -> Self {
        Self {
            stated: false,
            residual_px: 0.0,
            plane_angle_deg: None,
            plane_distance_mm: None,
            joint_offsets_deg: None,
            mirror_camera_centers_mm: [0.0; 2],
            mirror_camera_angles_deg: [0.0; 2],
            undetermined: vec![format!("the uncertainty: {reason}")],
            cameras: CameraCovariance::zeros(),
            cameras_stated: false,
            placements: Vec::new(),
            base_rotation_deg: None,
            base_translation_mm: None,
            tool_mm: None,
        }
    }

    /// Adds the uncertainty of head camera `k`'s turn, found again after it
    /// was knocked (`turn`: its covariance about the camera's own axes,
    /// rad^2), to its mirror camera in `plane`: a calibration made with the
    /// camera as found takes it as exact. `head` is the camera as found.
    pub fn add_head_camera_turn(
        &mut self,
        head: &Camera,
        k: usize,
        plane: &Plane,
        turn: &Matrix3<f64>,
    ) {
        if !self.cameras_stated {
            return;
        }
        // d (mirror camera k in the chart) / d (the head camera's turn).
        let base = plane.mirror_camera(head);
        let mirror_chart = |w: Vector3<f64>| {
            let moved = plane.mirror_camera(&head.turned(&w));
            chart(&[base, base], &[moved, base])
                .fixed_rows::<6>(0)
                .into_owned()
        };
        let mut g = SMatrix::<f64, 6, 3>::zeros();
        for j in 0..3 {
            let step = Vector3::ith(j, 1e-7);
            g.set_column(j, &((mirror_chart(step) - mirror_chart(-step)) / 2e-7));
        }
        let mut block = self.cameras.fixed_view_mut::<6, 6>(6 * k, 6 * k);
        block += g * turn * g.transpose();
        (self.mirror_camera_centers_mm, self.mirror_camera_angles_deg) =
            camera_sigmas(&self.cameras);
    }

    /// The file form.
    pub fn to_file(&self) -> formats::calibration::UncertaintyEntry {
        formats::calibration::UncertaintyEntry {
            residual_px: self.residual_px,
            plane_angle_deg: self.plane_angle_deg,
            plane_distance_mm: self.plane_distance_mm,
            joint_offsets_deg: self.joint_offsets_deg.clone(),
            mirror_camera_centers_mm: self.mirror_camera_centers_mm,
            mirror_camera_angles_deg: self.mirror_camera_angles_deg,
            undetermined: self.undetermined.clone(),
            placements: self
                .placements
                .iter()
                .map(|p| formats::calibration::PlaneSigmaEntry {
                    plane_angle_deg: p.angle_deg,
                    plane_distance_mm: p.distance_mm,
                })
                .collect(),
            base_translation_mm: self.base_translation_mm,
            base_rotation_deg: self.base_rotation_deg,
            tool_mm: self.tool_mm,
        }
    }

    /// The covariance (mm^2) of a point triangulated through `cameras` from
    /// `pixels`, each detected with this fit's pixel noise: the pixels' part
    /// and the cameras' part, linearised at `point`. `None` where a
    /// projection is undefined or the cameras' covariance is not stated.
    pub fn located_covariance(
        &self,
        cameras: &[Camera; 2],
        point: &Vector3<f64>,
    ) -> Option<Matrix3<f64>> {
        if !self.cameras_stated {
            return None;
        }
        // A: d pixels / d point (4x3); B: d pixels / d cameras (4x12).
        let project = |cams: &[Camera; 2], p: &Vector3<f64>| -> Option<SVector<f64, 4>> {
            let (l, r) = (cams[0].project(p).ok()?, cams[1].project(p).ok()?);
            Some(SVector::<f64, 4>::new(l.x, l.y, r.x, r.y))
        };
        let mut a = SMatrix::<f64, 4, 3>::zeros();
        for j in 0..3 {
            let h = 1e-4 * (1.0 + point[j].abs());
            let step = Vector3::ith(j, h);
            let d = project(cameras, &(point + step))? - project(cameras, &(point - step))?;
            a.set_column(j, &(d / (2.0 * h)));
        }
        let mut b = SMatrix::<f64, 4, CAMERA_PARAMS>::zeros();
        for j in 0..CAMERA_PARAMS {
            let h = if j % 6 < 3 { 1e-7 } else { 1e-4 };
            let step = CameraDelta::ith(j, h);
            let d = project(&perturb(cameras, &step), point)?
                - project(&perturb(cameras, &(-step)), point)?;
            b.set_column(j, &(d / (2.0 * h)));
        }
        // The triangulated point minimises the reprojection error, so
        // dX = -(A^T A)^-1 A^T (B dθ - dpixels).
        let normal = (a.transpose() * a).try_inverse()?;
        let gain = normal * a.transpose();
        let pixels = normal * (self.residual_px * self.residual_px);
        let from_cameras = gain * b * self.cameras * b.transpose() * gain.transpose();
        let total = pixels + from_cameras;
        total.iter().all(|v| v.is_finite()).then_some(total)
    }
}

/// Each mirror camera's RMS centre distance (mm) and rotation angle (deg)
/// from a chart covariance.
fn camera_sigmas(cameras: &CameraCovariance) -> ([f64; 2], [f64; 2]) {
    let rms = |o: usize| {
        (0..3)
            .map(|i| cameras[(o + i, o + i)].max(0.0))
            .sum::<f64>()
            .sqrt()
    };
    ([rms(3), rms(9)], [rms(0).to_degrees(), rms(6).to_degrees()])
}

/// The 1-sigma position error (mm) a covariance predicts: `sqrt(trace)`,
/// the RMS distance between the true and the located point.
pub fn rms_error_mm(covariance: &Matrix3<f64>) -> f64 {
    covariance.trace().max(0.0).sqrt()
}

/// The covariance of `f(params)` for a parameter covariance `cov` over the
/// first `inputs.len()` parameters: `G P G^T`, with `G` by central
/// differences of `f` (into the camera chart) around `inputs`.
pub(crate) fn propagate_to_cameras(
    cov: &Covariance,
    inputs: &[f64],
    steps: &[f64],
    f: impl Fn(&[f64]) -> Option<CameraDelta>,
) -> Option<CameraCovariance> {
    let n = inputs.len();
    let mut g = DMatrix::<f64>::zeros(CAMERA_PARAMS, n);
    let mut probe = inputs.to_vec();
    for j in 0..n {
        probe[j] = inputs[j] + steps[j];
        let plus = f(&probe)?;
        probe[j] = inputs[j] - steps[j];
        let minus = f(&probe)?;
        probe[j] = inputs[j];
        let column = (plus - minus) / (2.0 * steps[j]);
        g.column_mut(j).copy_from_slice(column.as_slice());
    }
    let p = cov.matrix.view((0, 0), (n, n));
    let out = &g * p * g.transpose();
    let out = CameraCovariance::from_iterator(out.iter().copied());
    out.iter().all(|v| v.is_finite()).then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use geometry::sim::nico_scene;

    #[test]
    fn the_chart_inverts_perturb() {
        let cams = nico_scene().rig.cameras;
        let delta = CameraDelta::from_iterator((0..12).map(|i| 0.001 * (i as f64 - 5.5)));
        let back = chart(&cams, &perturb(&cams, &delta));
        assert!((back - delta).norm() < 1e-12, "{back} vs {delta}");
    }

    /// A head camera found again to a turn's covariance: the spread of a
    /// point located through its mirror camera, when the camera is turned
    /// by draws of that covariance, is what the located covariance states.
    #[test]
    fn a_found_cameras_turn_spreads_located_points_as_stated() {
        use geometry::triangulate::triangulate;
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};

        let scene = nico_scene();
        let (head, plane) = (scene.rig.cameras, scene.mirrors[0].plane);
        let mirrored = head.map(|c| plane.mirror_camera(&c));
        // A point behind the head, seen in the glass (the mirror cameras
        // see real points in front of the mirror).
        let point = Vector3::new(30.0, 50.0, -100.0);
        let pixels = mirrored.map(|c| c.project(&point).unwrap());
        // Tilt, pan and roll of 0.02, 0.03 and 0.05 deg, pan and roll related.
        let s = Vector3::new(0.02, 0.03, 0.05).map(f64::to_radians);
        let mut turn = Matrix3::from_diagonal(&s.component_mul(&s));
        turn[(1, 2)] = 0.5 * s.y * s.z;
        turn[(2, 1)] = turn[(1, 2)];
        let mut u = Uncertainty::from_cameras(CameraCovariance::zeros(), 0.0);
        u.add_head_camera_turn(&head[0], 0, &plane, &turn);
        let stated = u.located_covariance(&mirrored, &point).unwrap();

        let root = turn.cholesky().unwrap().l();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let draws = 4000;
        let mut spread = Matrix3::zeros();
        for _ in 0..draws {
            let z = Vector3::from_fn(|_, _| StandardNormal.sample(&mut rng));
            let turned = plane.mirror_camera(&head[0].turned(&(root * z)));
            let p = triangulate([&turned, &mirrored[1]], pixels).unwrap() - point;
            spread += p * p.transpose() / f64::from(draws);
        }
        let (a, b) = (rms_error_mm(&stated), rms_error_mm(&spread));
        assert!(a > 5.0, "a 0.05 deg turn moves the point by {a} mm");
        assert!((a / b - 1.0).abs() < 0.05, "stated {a} mm, drawn {b} mm");
        assert!(
            (stated - spread).norm() < 0.1 * spread.norm(),
            "stated {stated}, drawn {spread}"
        );
        // Only the turned camera's mirror camera is less certain.
        assert!(u.mirror_camera_angles_deg[0] > 0.05 && u.mirror_camera_angles_deg[1] == 0.0);
        assert_eq!(u.mirror_camera_centers_mm, [0.0, 0.0]);
    }
}
