//! The paper's experiment on simulated data: for each mirror placement, 50
//! training and 100 test poses (plus 100 direct poses); every method trained
//! on the first `n` training poses for each size `n`, evaluated with the
//! paper's four metrics. Two references: the *oracle* (true mirror cameras,
//! the robot's nominal arm model) and the *noise floor* (true mirror cameras
//! and true end-effector positions: what pixel noise alone costs).

use formats::calibration::PlaneEntry;
use formats::evaluation::Evaluation;
use geometry::sim::{Counts, NoiseModel, Scene, generate};
use geometry::{Camera, GeometryError};
use nalgebra::Matrix3;
use serde::Serialize;

use crate::calibrate::{Calibration, Method, calibrate};
use crate::evaluate::{evaluate, evaluate_against};

/// The paper's reported means (Hart & Scassellati 2012): mirror 3D mm,
/// direct 3D mm, mirror 2D px, direct 2D px.
pub const PAPER_FIGURES: PaperFigures = PaperFigures {
    mirror_3d_mm: 31.55,
    direct_3d_mm: 5.12,
    mirror_2d_px: 18.47,
    direct_2d_px: 5.66,
};

/// The four headline figures.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PaperFigures {
    /// Mean 3D error through the mirror, mm.
    pub mirror_3d_mm: f64,
    /// Mean 3D error of direct views, mm.
    pub direct_3d_mm: f64,
    /// Mean 2D error through the mirror, px.
    pub mirror_2d_px: f64,
    /// Mean 2D error of direct views, px.
    pub direct_2d_px: f64,
}

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct ExperimentConfig {
    /// Preset name, for the report.
    pub preset: String,
    /// Mirror placements to use.
    pub mirrors: Vec<usize>,
    /// Training sizes.
    pub sizes: Vec<usize>,
    /// Samples per placement.
    pub counts: Counts,
    /// Noise applied by the simulator.
    pub noise: NoiseModel,
    /// Seed of the simulator.
    pub seed: u64,
}

impl ExperimentConfig {
    /// The paper's protocol: three placements, 50/100 poses, sizes 3..=50.
    pub fn paper(preset: &str, noise: NoiseModel, seed: u64) -> Self {
        Self {
            preset: preset.into(),
            mirrors: vec![0, 1, 2],
            sizes: (3..=50).collect(),
            counts: Counts::PAPER,
            noise,
            seed,
        }
    }

    /// A small version for tests: fewer sizes and test poses.
    pub fn quick(preset: &str, noise: NoiseModel, seed: u64) -> Self {
        Self {
            sizes: vec![3, 5, 10, 20],
            counts: Counts {
                train: 20,
                test: 30,
                direct: 30,
            },
            ..Self::paper(preset, noise, seed)
        }
    }
}

/// How far a calibration is from the simulator's truth.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TruthError {
    /// Mirror camera centre errors, mm (left, right).
    pub center_mm: [f64; 2],
    /// Mirror camera rotation errors, deg (left, right).
    pub rotation_deg: [f64; 2],
    /// Rotation errors of the estimate the refinement started from, deg.
    pub initial_rotation_deg: [f64; 2],
    /// Angle between estimated and true mirror normals, deg.
    pub plane_angle_deg: Option<f64>,
    /// Error of the plane offset, mm.
    pub plane_distance_mm: Option<f64>,
    /// Largest error of the estimated encoder offsets, rad.
    pub joint_offsets_max_rad: Option<f64>,
}

/// One method trained on one size for one mirror.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Run {
    /// Method name.
    pub method: String,
    /// Training poses.
    pub size: usize,
    /// Test metrics (absent if calibration failed).
    pub evaluation: Option<Evaluation>,
    /// Distance from the truth.
    pub truth_error: Option<TruthError>,
    /// Training RMS reprojection error, px.
    pub train_rms_px: Option<f64>,
    /// Why calibration or evaluation failed.
    pub error: Option<String>,
}

/// Everything measured on one mirror placement.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MirrorResult {
    /// Placement index.
    pub mirror: usize,
    /// The true mirror plane.
    pub plane: PlaneEntry,
    /// True mirror cameras with the nominal arm model.
    pub oracle: Evaluation,
    /// True mirror cameras and true end-effector positions.
    pub noise_floor: Evaluation,
    /// Every method at every size.
    pub runs: Vec<Run>,
}

/// Means over mirror placements, for one method (or reference) and size.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    /// Method, `oracle` or `noise floor`.
    pub method: String,
    /// Training poses (0 for the references).
    pub size: usize,
    /// Mean over placements of the mean mirror 3D error, mm.
    pub mirror_3d_mm: Option<f64>,
    /// Mean over placements of the median mirror 3D error, mm (robust to
    /// the rare sample whose rays nearly miss each other).
    pub mirror_3d_mm_median: Option<f64>,
    /// Likewise, mirror 2D, px.
    pub mirror_2d_px: Option<f64>,
    /// Likewise, direct 3D, mm.
    pub direct_3d_mm: Option<f64>,
    /// Mean over placements of the median direct 3D error, mm.
    pub direct_3d_mm_median: Option<f64>,
    /// Likewise, direct 2D, px.
    pub direct_2d_px: Option<f64>,
    /// Placements where calibration failed.
    pub failures: usize,
}

/// The experiment's full result (written as JSON).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ExperimentResult {
    /// Preset name.
    pub preset: String,
    /// Pixel noise sigma, px.
    pub pixel_sigma: f64,
    /// True encoder offsets, rad.
    pub joint_offsets: Vec<f64>,
    /// Simulator seed.
    pub seed: u64,
    /// Training sizes.
    pub sizes: Vec<usize>,
    /// The paper's figures, for comparison.
    pub paper: PaperFigures,
    /// Per placement.
    pub mirrors: Vec<MirrorResult>,
    /// Means over placements per method and size, then `oracle` and `noise floor`.
    pub summary: Vec<Summary>,
}

impl ExperimentResult {
    /// The summary row for a method (or reference) and size.
    pub fn summary_for(&self, method: &str, size: usize) -> Option<&Summary> {
        self.summary
            .iter()
            .find(|s| s.method == method && s.size == size)
    }
}

/// Angle of a rotation matrix, robust near 0 and for slightly non-orthonormal input.
pub fn rotation_angle(r: &Matrix3<f64>) -> f64 {
    let skew = nalgebra::Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    );
    (0.5 * skew.norm()).atan2(0.5 * (r.trace() - 1.0))
}

/// Rotation between two cameras' orientations, rad.
pub fn rotation_error(a: &Camera, b: &Camera) -> f64 {
    rotation_angle(&(a.camera_from_world * b.camera_from_world.transpose()))
}

fn truth_error(cal: &Calibration, truth: &geometry::sim::Truth) -> TruthError {
    let t = &truth.mirror_cameras;
    let per_camera = |f: &dyn Fn(usize) -> f64| [f(0), f(1)];
    let true_plane = truth.mirror.plane;
    TruthError {
        center_mm: per_camera(&|k| (cal.mirror_cameras[k].center - t[k].center).norm()),
        rotation_deg: per_camera(&|k| rotation_error(&cal.mirror_cameras[k], &t[k]).to_degrees()),
        initial_rotation_deg: per_camera(&|k| {
            rotation_error(&cal.initial_cameras[k], &t[k]).to_degrees()
        }),
        plane_angle_deg: cal.plane.map(|p| {
            p.normal
                .dot(&true_plane.normal)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        }),
        plane_distance_mm: cal.plane.map(|p| (p.distance - true_plane.distance).abs()),
        joint_offsets_max_rad: cal.joint_offsets.as_ref().map(|o| {
            o.iter()
                .zip(&truth.joint_offsets)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        }),
    }
}

/// Runs the experiment. `progress` is called once per placement finished.
pub fn run(
    scene: &Scene,
    config: &ExperimentConfig,
    mut progress: impl FnMut(usize),
) -> Result<ExperimentResult, GeometryError> {
    let mut mirrors = Vec::new();
    for &m in &config.mirrors {
        let data = generate(scene, m, &config.noise, config.counts, config.seed)?;
        let test: Vec<_> = data.test.iter().chain(&data.direct).cloned().collect();
        let true_points: Vec<_> = data
            .truth
            .test_points
            .iter()
            .chain(&data.truth.direct_points)
            .copied()
            .collect();
        let reference_error =
            |e: crate::calibrate::CalibrateError| GeometryError::Degenerate(e.to_string());
        let oracle = evaluate(&data.rig, &data.truth.mirror_cameras, None, &test)
            .map_err(reference_error)?;
        let floor = evaluate_against(&data.rig, &data.truth.mirror_cameras, &test, &true_points)
            .map_err(reference_error)?;
        let mut runs = Vec::new();
        for method in Method::ALL {
            for &size in config.sizes.iter().filter(|&&n| n <= data.train.len()) {
                let outcome = calibrate(&data.rig, &data.train[..size], method).and_then(|cal| {
                    let errors = evaluate(
                        &data.rig,
                        &cal.mirror_cameras,
                        cal.joint_offsets.as_deref(),
                        &test,
                    )?;
                    Ok((cal, errors))
                });
                runs.push(match outcome {
                    Ok((cal, errors)) => Run {
                        method: method.to_string(),
                        size,
                        evaluation: Some(errors.summary()),
                        truth_error: Some(truth_error(&cal, &data.truth)),
                        train_rms_px: Some(cal.train_rms_px),
                        error: None,
                    },
                    Err(e) => Run {
                        method: method.to_string(),
                        size,
                        evaluation: None,
                        truth_error: None,
                        train_rms_px: None,
                        error: Some(e.to_string()),
                    },
                });
            }
        }
        mirrors.push(MirrorResult {
            mirror: m,
            plane: PlaneEntry {
                normal: data.truth.mirror.plane.normal.into_inner().into(),
                distance: data.truth.mirror.plane.distance,
            },
            oracle: oracle.summary(),
            noise_floor: floor.summary(),
            runs,
        });
        progress(m);
    }
    let summary = summarize(&mirrors, config);
    Ok(ExperimentResult {
        preset: config.preset.clone(),
        pixel_sigma: config.noise.pixel_sigma,
        joint_offsets: config.noise.joint_offsets.clone(),
        seed: config.seed,
        sizes: config.sizes.clone(),
        paper: PAPER_FIGURES,
        mirrors,
        summary,
    })
}

fn mean_of<'a>(
    evals: impl Iterator<Item = &'a Evaluation> + Clone,
    f: fn(&Evaluation) -> Option<f64>,
) -> Option<f64> {
    let values: Vec<f64> = evals.filter_map(f).collect();
    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
}

fn summary_row<'a>(
    method: &str,
    size: usize,
    evals: impl Iterator<Item = &'a Evaluation> + Clone,
    failures: usize,
) -> Summary {
    Summary {
        method: method.into(),
        size,
        mirror_3d_mm: mean_of(evals.clone(), |e| e.mirror_3d_mm),
        mirror_3d_mm_median: mean_of(evals.clone(), |e| e.mirror_3d_mm_median),
        mirror_2d_px: mean_of(evals.clone(), |e| e.mirror_2d_px),
        direct_3d_mm: mean_of(evals.clone(), |e| e.direct_3d_mm),
        direct_3d_mm_median: mean_of(evals.clone(), |e| e.direct_3d_mm_median),
        direct_2d_px: mean_of(evals, |e| e.direct_2d_px),
        failures,
    }
}

fn summarize(mirrors: &[MirrorResult], config: &ExperimentConfig) -> Vec<Summary> {
    let mut out = Vec::new();
    for method in Method::ALL {
        for &size in &config.sizes {
            let runs: Vec<&Run> = mirrors
                .iter()
                .flat_map(|m| &m.runs)
                .filter(|r| r.method == method.as_str() && r.size == size)
                .collect();
            if runs.is_empty() {
                continue;
            }
            let failures = runs.iter().filter(|r| r.evaluation.is_none()).count();
            out.push(summary_row(
                method.as_str(),
                size,
                runs.iter().filter_map(|r| r.evaluation.as_ref()),
                failures,
            ));
        }
    }
    out.push(summary_row(
        "oracle",
        0,
        mirrors.iter().map(|m| &m.oracle),
        0,
    ));
    out.push(summary_row(
        "noise floor",
        0,
        mirrors.iter().map(|m| &m.noise_floor),
        0,
    ));
    out
}

fn cell(v: Option<f64>) -> String {
    match v {
        None => "-".into(),
        // A mean dominated by a sample whose rays (nearly) diverge.
        Some(v) if v >= 1e5 => format!("{v:.1e}"),
        Some(v) => format!("{v:.2}"),
    }
}

/// The paper's results table for the largest training size, and a learning
/// curve at a few sizes, as plain text.
pub fn table(result: &ExperimentResult) -> String {
    let largest = result.sizes.iter().copied().max().unwrap_or(0);
    let mut s = format!(
        "Mirror perspective-taking, preset {} (pixel noise {:.2} px, encoder offsets {:?} rad, seed {}), mirror placements {:?}\n\n",
        result.preset,
        result.pixel_sigma,
        result.joint_offsets,
        result.seed,
        result.mirrors.iter().map(|m| m.mirror).collect::<Vec<_>>()
    );
    s += &format!("Mean errors at {largest} training poses, averaged over placements:\n");
    s += &format!(
        "  {:<30} {:>12} {:>10} {:>12} {:>12} {:>12}\n",
        "", "mirror 3D mm", "(median)", "direct 3D mm", "mirror 2D px", "direct 2D px"
    );
    let p = result.paper;
    s += &format!(
        "  {:<30} {:>12.2} {:>10} {:>12.2} {:>12.2} {:>12.2}\n",
        "Hart & Scassellati 2012 (Nico)",
        p.mirror_3d_mm,
        "-",
        p.direct_3d_mm,
        p.mirror_2d_px,
        p.direct_2d_px
    );
    let row = |label: &str, r: Option<&Summary>| match r {
        Some(r) => format!(
            "  {:<30} {:>12} {:>10} {:>12} {:>12} {:>12}{}\n",
            label,
            cell(r.mirror_3d_mm),
            cell(r.mirror_3d_mm_median),
            cell(r.direct_3d_mm),
            cell(r.mirror_2d_px),
            cell(r.direct_2d_px),
            if r.failures > 0 {
                format!("  ({} failed)", r.failures)
            } else {
                String::new()
            }
        ),
        None => String::new(),
    };
    for method in Method::ALL {
        s += &row(
            &format!("{method} (ours)"),
            result.summary_for(method.as_str(), largest),
        );
    }
    s += &row(
        "oracle: true mirror cameras",
        result.summary_for("oracle", 0),
    );
    s += &row(
        "noise floor: + true kinematics",
        result.summary_for("noise floor", 0),
    );

    s += "\nLearning curve, mirror 3D mm (median) / mirror 2D px (mean), over placements:\n";
    s += &format!("  {:>5}", "poses");
    for method in Method::ALL {
        s += &format!(" {:>20}", method.as_str());
    }
    s += "\n";
    for &n in result
        .sizes
        .iter()
        .filter(|n| [3, 5, 10, 20, 30, 50].contains(*n) || **n == largest)
    {
        s += &format!("  {n:>5}");
        for method in Method::ALL {
            let r = result.summary_for(method.as_str(), n);
            let text = r.map_or("-".into(), |r| {
                format!("{} / {}", cell(r.mirror_3d_mm_median), cell(r.mirror_2d_px))
            });
            s += &format!(" {text:>20}");
        }
        s += "\n";
    }
    let reference = |name: &str| {
        result.summary_for(name, 0).map_or("-".into(), |r| {
            format!("{} / {}", cell(r.mirror_3d_mm_median), cell(r.mirror_2d_px))
        })
    };
    s += &format!(
        "  oracle {}   noise floor {}\n",
        reference("oracle"),
        reference("noise floor")
    );
    s
}
