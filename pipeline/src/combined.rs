//! One calibration across the run's placements when it ends
//! (`--estimate`): every placement's training and direct samples, read
//! back from its mirror stage's journal, solved together with one plane
//! per placement, the rig's cameras, one arm and the arm's base and/or
//! tool; compared with the simulator's truth.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result, bail};
use geometry::{Role, Sample};
use messages::topics;
use mirror_proc::calibrate::{CalibrateOptions, Estimate, calibrate_placements};
use nalgebra::Vector3;
use serde::Serialize;

use crate::run::{Run, plan_for};

/// The combined calibration and how far it is from the truth.
#[derive(Debug, Clone, Serialize)]
pub struct Combined {
    /// What was estimated beside the planes (`base`, `tool`).
    pub estimated: Vec<&'static str>,
    /// The calibration, as `mirror_proc calibrate` writes it.
    pub calibration: formats::calibration::CalibrationFile,
    /// Per placement: its plane against the truth.
    pub placements: Vec<PlaneErrors>,
    /// RMS distance between where the calibrated arm puts the marker and
    /// where it is, over every sample used, mm.
    pub marker_rms_mm: f64,
    /// The same for the rig the stages were given, encoders taken as
    /// read, mm.
    pub marker_rms_mm_rig: f64,
}

/// One placement's plane against the truth.
#[derive(Debug, Clone, Serialize)]
pub struct PlaneErrors {
    /// The mirror placement.
    pub mirror: usize,
    /// Angle between the calibrated and the true normal, degrees.
    pub plane_angle_deg: f64,
    /// Difference of the plane offsets, mm.
    pub plane_distance_mm: f64,
}

/// The training and direct samples of the journal at `path`, their `J`
/// left to the arm being corrected.
fn journaled(path: &Path) -> Result<Vec<Sample>> {
    let recovered = runtime::journal::read(path).with_context(|| format!("{}", path.display()))?;
    Ok(recovered
        .messages::<topics::Samples>()
        .filter(|s| s.role == Role::Train as u32 || s.role == Role::Direct as u32)
        .map(|s| {
            let mut sample = s.to_sample();
            // J from the joints through the arm being corrected, not the
            // kinematics stage's (which used the rig as given).
            sample.model_point = None;
            sample
        })
        .collect())
}

/// Calibrates across the placements `run` has finished, estimating
/// `estimate`; errors name the placement's journal or what cannot be
/// estimated.
pub fn calibrate(run: &Run, estimate: Estimate) -> Result<Combined> {
    let config = &run.config;
    let dir = |m: usize| run.out.join(format!("mirror{m}"));
    let Some(&first) = config.mirrors.first() else {
        bail!("--estimate: the run has no placements");
    };
    let rig_path = dir(first).join("rig.toml");
    let rig = formats::rig::read(&rig_path)?;
    let mut sets = Vec::new();
    let mut truth: Vec<BTreeMap<u64, Vector3<f64>>> = Vec::new();
    let mut planes = Vec::new();
    for &m in &config.mirrors {
        sets.push(journaled(&dir(m).join("journal.mcap"))?);
        let (data, _) = plan_for(config, m)?;
        let t = &data.truth;
        truth.push(
            data.train
                .iter()
                .zip(&t.train_points)
                .chain(data.test.iter().zip(&t.test_points))
                .chain(data.direct.iter().zip(&t.direct_points))
                .map(|(s, p)| (s.pose, *p))
                .collect(),
        );
        planes.push(t.mirror.plane);
    }
    let placements: Vec<&[Sample]> = sets.iter().map(Vec::as_slice).collect();
    let cal = calibrate_placements(
        &rig,
        &placements,
        config.method,
        estimate,
        CalibrateOptions::default(),
    )
    .map_err(|e| {
        let e = match e {
            mirror_proc::calibrate::CalibrateError::InPlacement { placement, source } => {
                anyhow::anyhow!("mirror {}: {source}", config.mirrors[placement])
            }
            e => anyhow::anyhow!(e),
        };
        e.context("the combined calibration (--estimate)")
    })?;
    let corrected = cal.corrected_rig(&rig);
    let offsets = cal.joint_offsets.clone().unwrap_or_default();
    let marker_rms = |rig: &geometry::Rig, offsets: &[f64]| -> Result<f64> {
        let arm = rig.arm.as_ref().context("the rig has no [arm]")?;
        let mut sum = 0.0;
        let mut n = 0usize;
        for (samples, truth) in sets.iter().zip(&truth) {
            for s in samples {
                let q = s.joints.as_deref().unwrap_or_default();
                let at = arm.end_effector(q, offsets)?;
                let true_point = truth
                    .get(&s.pose)
                    .with_context(|| format!("pose {} is not in the plan", s.pose))?;
                sum += (at - true_point).norm_squared();
                n += 1;
            }
        }
        Ok((sum / n.max(1) as f64).sqrt())
    };
    let placements = cal
        .placements
        .iter()
        .zip(&planes)
        .zip(&config.mirrors)
        .map(|((fit, truth), &mirror)| {
            let plane = fit.plane.expect("the joint methods solve a plane");
            PlaneErrors {
                mirror,
                plane_angle_deg: plane.normal.angle(&truth.normal).to_degrees(),
                plane_distance_mm: (plane.distance - truth.distance).abs(),
            }
        })
        .collect();
    Ok(Combined {
        estimated: [("base", estimate.base), ("tool", estimate.tool)]
            .into_iter()
            .filter_map(|(name, on)| on.then_some(name))
            .collect(),
        marker_rms_mm: marker_rms(&corrected, &offsets)?,
        marker_rms_mm_rig: marker_rms(&rig, &[])?,
        calibration: cal.to_file(&rig),
        placements,
    })
}

/// The combined calibration as the lines the run prints.
pub fn lines(c: &Combined) -> String {
    let cal = &c.calibration;
    let u = cal.uncertainty.as_ref();
    let sigma =
        |v: Option<f64>, unit: &str| v.map_or(String::new(), |v| format!(" ± {v:.3} {unit}"));
    let mut out = format!(
        "combined calibration across mirrors {:?} ({} mirror + {} direct samples, {} estimated): {:.2} px RMS, fit {}\n",
        c.placements.iter().map(|p| p.mirror).collect::<Vec<_>>(),
        cal.samples,
        cal.direct_samples,
        c.estimated.join(" and "),
        cal.train_rms_px,
        cal.fit.map_or("not judged", |f| f.as_str()),
    );
    if let Some(b) = cal.world_from_base {
        out += &format!(
            "  base at ({:.1}, {:.1}, {:.1}) mm{}, rotation{}\n",
            b[3],
            b[7],
            b[11],
            sigma(u.and_then(|u| u.base_translation_mm), "mm"),
            sigma(u.and_then(|u| u.base_rotation_deg), "deg"),
        );
    }
    if let Some(t) = cal.tool {
        out += &format!(
            "  tool at ({:.2}, {:.2}, {:.2}) mm{}\n",
            t[0],
            t[1],
            t[2],
            sigma(u.and_then(|u| u.tool_mm), "mm"),
        );
    }
    out += &format!(
        "  marker placed {:.2} mm RMS from the truth (the rig as given: {:.2} mm)\n",
        c.marker_rms_mm, c.marker_rms_mm_rig
    );
    for p in &c.placements {
        out += &format!(
            "  mirror {}: plane {:.4} deg, {:.3} mm from the truth\n",
            p.mirror, p.plane_angle_deg, p.plane_distance_mm
        );
    }
    out
}
