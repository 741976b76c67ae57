//! What a run reports: per placement, the mirror stage's report compared
//! with the simulator's truth and every stage's latencies; the paper's
//! table and the latency table.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use formats::calibration::CalibrationFile;
use geometry::sim::{HIDDEN_OBJECT_ID, SimWorld};
use mirror_proc::calibrate::Method;
use mirror_proc::experiment::{PAPER_FIGURES, rotation_error};
use mirror_proc::live::LiveReport;
use serde::Serialize;

use crate::args::ReportFormat;
use crate::combined::Combined;
use crate::run::Run;
use crate::split::Side;

/// Writes the run's `OUT/report.json` and prints it (`format`): the tables
/// (the paper's one only where the mirror stage ran), or the JSON. A run
/// that ends without a calibration fails, whatever else it did.
pub fn finish(
    results: &[PlacementResult],
    combined: Option<&Combined>,
    run: &Run,
    out: &Path,
    format: ReportFormat,
    side: Option<Side>,
    replayed: bool,
) -> Result<()> {
    let path = out.join("report.json");
    let mut json = serde_json::json!({
        "config": run.config,
        "realtime_priority": run.realtime,
        "paper": PAPER_FIGURES,
        "placements": results,
    });
    if let Some(c) = combined {
        json["combined"] = serde_json::to_value(c)?;
    }
    let text = serde_json::to_string_pretty(&json)? + "\n";
    std::fs::write(&path, &text).with_context(|| format!("{}: cannot write", path.display()))?;
    if format == ReportFormat::Json {
        print!("{text}");
    } else {
        if side != Some(Side::Robot) {
            print!("{}", table(results, run.config.method));
            print!("{}", epoch_lines(results));
        }
        if let Some(c) = combined {
            print!("{}", crate::combined::lines(c));
        }
        print!("{}", latency_table(results));
        print!("{}", cpu_table(results));
        if replayed {
            println!(
                "report: {}  (in {}: recording.mcap, mirror_report.json, rig.toml, plan.csv, \
                 stages.log, journal.mcap; compare with `replay diff`)",
                path.display(),
                out.display()
            );
        } else {
            println!(
                "report: {}  (per placement: {}/mirror<i>/{{report.json, recording.mcap, rig.toml, \
                 plan.csv, stages.log, journal.mcap, arm_journal.mcap}})",
                path.display(),
                out.display()
            );
        }
    }
    let uncalibrated: Vec<String> = results
        .iter()
        .filter_map(|r| Some((r.mirror, r.report.as_ref()?)))
        .filter(|(_, report)| report.calibration.is_none())
        .map(|(mirror, report)| {
            format!(
                "mirror {mirror}: no calibration: {}",
                report.last_error.as_deref().unwrap_or("no reason given")
            )
        })
        .collect();
    if !uncalibrated.is_empty() {
        bail!("{}", uncalibrated.join("; "));
    }
    Ok(())
}

/// What the table shows for one placement.
#[derive(Debug, Clone, Serialize)]
pub struct PlacementResult {
    /// The mirror placement.
    pub mirror: usize,
    /// The mirror stage's report (none on the robot side of a split run).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub report: Option<LiveReport>,
    /// Its calibration against the simulator's truth (the world as it is
    /// at the run's end).
    #[serde(flatten)]
    pub truth: Option<TruthErrors>,
    /// Where the world changed during the run: each epoch against the
    /// world of its time.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub epochs: Vec<EpochTruth>,
    /// Stage restarts.
    pub restarts: u32,
    /// Wall time of the placement, s.
    pub seconds: f64,
    /// The recording, if one was made.
    pub recording: Option<PathBuf>,
    /// Each stage process's latencies (HDR histograms) and counters.
    pub stages: Vec<runtime::stats::StageSummary>,
}

/// The errors of a calibration against the simulator's truth.
#[derive(Debug, Clone, Default, Serialize)]
pub struct TruthErrors {
    /// Angle between the calibrated and the true mirror normal, degrees.
    pub plane_angle_deg: Option<f64>,
    /// Distance between the calibrated and the true plane offsets, mm.
    pub plane_distance_mm: Option<f64>,
    /// Distance of each mirror camera's centre from the truth, mm.
    pub camera_center_mm: Option<[f64; 2]>,
    /// Rotation of each mirror camera from the truth, degrees.
    pub camera_rotation_deg: Option<[f64; 2]>,
    /// How far the hidden object was located from where it is, mm.
    pub hidden_object_error_mm: Option<f64>,
    /// The stated 1-sigma of the plane angle, degrees.
    pub plane_angle_sigma_deg: Option<f64>,
    /// The stated 1-sigma of the plane's distance, mm.
    pub plane_distance_sigma_mm: Option<f64>,
    /// The stated 1-sigma of the hidden object's position, mm.
    pub hidden_object_sigma_mm: Option<f64>,
    /// Each head camera the calibration found again after it moved: its
    /// orientation's angle from the truth, degrees, by name.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub head_cameras_deg: Vec<(String, f64)>,
}

impl TruthErrors {
    /// Compares `report`'s final calibration and located objects with
    /// `world`, the world as it is at the run's end.
    pub fn of(report: &LiveReport, world: &SimWorld) -> Self {
        let hidden = world.fixed.iter().find(|f| f.id == HIDDEN_OBJECT_ID);
        Self {
            hidden_object_error_mm: hidden.and_then(|h| {
                report
                    .located
                    .get(&h.id)
                    .map(|p| (nalgebra::Vector3::from(*p) - h.center).norm())
            }),
            hidden_object_sigma_mm: hidden
                .and_then(|h| report.located_sigma_mm.get(&h.id).copied()),
            ..Self::of_calibration(report.calibration.as_ref(), world)
        }
    }

    /// Compares a calibration with `world`, the world it was made in.
    pub fn of_calibration(cal: Option<&CalibrationFile>, world: &SimWorld) -> Self {
        let Some(mirror) = world.mirror else {
            return Self::default();
        };
        let truth_plane = mirror.plane;
        let true_cameras = world.rig.cameras.map(|c| truth_plane.mirror_camera(&c));
        let cams = cal.map(|c| c.mirror_cameras(&world.rig));
        let plane = cal.and_then(|c| c.plane());
        let head_cameras_deg = cal
            .map(|c| &c.head_cameras)
            .into_iter()
            .flatten()
            .filter_map(|found| {
                let k = world.rig.names.iter().position(|n| *n == found.name)?;
                let r = nalgebra::Matrix3::from_row_slice(&found.camera_from_world);
                let turn = r * world.rig.cameras[k].camera_from_world.transpose();
                let angle = nalgebra::Rotation3::from_matrix(&turn).angle().to_degrees();
                Some((found.name.clone(), angle))
            })
            .collect();
        Self {
            plane_angle_deg: plane.map(|p| {
                p.normal
                    .dot(&truth_plane.normal)
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees()
            }),
            plane_distance_mm: plane.map(|p| (p.distance - truth_plane.distance).abs()),
            camera_center_mm: cams
                .map(|c| [0, 1].map(|k| (c[k].center - true_cameras[k].center).norm())),
            camera_rotation_deg: cams
                .map(|c| [0, 1].map(|k| rotation_error(&c[k], &true_cameras[k]).to_degrees())),
            plane_angle_sigma_deg: cal
                .and_then(|c| c.uncertainty.as_ref())
                .and_then(|u| u.plane_angle_deg),
            plane_distance_sigma_mm: cal
                .and_then(|c| c.uncertainty.as_ref())
                .and_then(|u| u.plane_distance_mm),
            head_cameras_deg,
            ..Self::default()
        }
    }
}

/// One epoch of a run whose world changed, against the world of its time.
#[derive(Debug, Clone, Serialize)]
pub struct EpochTruth {
    /// Its number, from 1.
    pub epoch: u32,
    /// The pose the change before it was made at (the event's), if any.
    pub changed_at_pose: Option<u64>,
    /// What the stage said changed, and at which pose it said the change
    /// began and was found.
    pub after: Option<String>,
    /// See `after`.
    pub began_at_pose: u64,
    /// See `after`.
    pub found_at_pose: Option<u64>,
    /// Poses of the plan from the change to where it was found, both
    /// counted (1: found at the first pose of the changed world).
    pub found_after_poses: Option<usize>,
    /// Changes made within the epoch that were never found (pose ids):
    /// its calibration is scored against the world it began in.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub unnoticed_changes: Vec<u64>,
    /// Its last calibration against the world of its time.
    #[serde(flatten)]
    pub truth: TruthErrors,
}

/// Where the world changed during a run: each epoch's last calibration
/// against the world of its time (empty when nothing changed).
pub fn epoch_lines(results: &[PlacementResult]) -> String {
    let mut s = String::new();
    for r in results.iter().filter(|r| !r.epochs.is_empty()) {
        if s.is_empty() {
            s += "\nWhen the world changed: each epoch's calibration against the world of its time\n";
        }
        for e in &r.epochs {
            let change = match (&e.after, e.changed_at_pose, e.found_at_pose) {
                (Some(what), changed, Some(found)) => format!(
                    "after the {what} moved (changed at pose {}, found at pose {found}: within {} poses)",
                    changed.map_or("-".into(), |p| p.to_string()),
                    e.found_after_poses.map_or("-".into(), |n| n.to_string())
                ),
                _ => "from the start".into(),
            };
            let cameras: String = e
                .truth
                .head_cameras_deg
                .iter()
                .map(|(name, deg)| {
                    format!(", camera {name} found again {deg:.3} deg from the truth")
                })
                .collect();
            let unnoticed: String = e
                .unnoticed_changes
                .iter()
                .map(|p| format!("; the world changed unnoticed at pose {p}"))
                .collect();
            let sigma = match (
                e.truth.plane_angle_sigma_deg,
                e.truth.plane_distance_sigma_mm,
            ) {
                (Some(a), Some(d)) => format!(" (1-sigma {a:.3} deg / {d:.3} mm)"),
                _ => String::new(),
            };
            s += &format!(
                "  mirror {}, epoch {} {change}: plane {} deg / {} mm from the truth{sigma}{cameras}{unnoticed}\n",
                r.mirror,
                e.epoch,
                fine(e.truth.plane_angle_deg),
                fine(e.truth.plane_distance_mm),
            );
        }
        if let Some(why) = r.report.as_ref().and_then(|rep| rep.last_error.as_ref()) {
            s += &format!("  mirror {}: {why}\n", r.mirror);
        }
    }
    s
}

/// A small angle: three decimals.
fn fine(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.3}"))
}

fn cell(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.2}"))
}

/// Per stage and placement: latency percentiles (from each stage's HDR
/// histograms) and the drop counters.
pub fn latency_table(results: &[PlacementResult]) -> String {
    let mut s = String::from("\nLatency per stage, ms (HDR histograms)\n");
    s += &format!(
        "  {:<10} {:<14} {:<20} {:>7} {:>8} {:>8} {:>8} {:>8}\n",
        "placement", "stage", "", "count", "median", "p90", "p99", "max"
    );
    for r in results {
        for stage in &r.stages {
            for (name, l) in &stage.latencies {
                s += &format!(
                    "  {:<10} {:<14} {:<20} {:>7} {:>8.2} {:>8.2} {:>8.2} {:>8.2}\n",
                    format!("mirror {}", r.mirror),
                    stage.stage,
                    name,
                    l.count,
                    l.p50_ms,
                    l.p90_ms,
                    l.p99_ms,
                    l.max_ms
                );
            }
        }
        let counters: Vec<String> = r
            .stages
            .iter()
            .flat_map(|st| {
                st.counters
                    .iter()
                    .filter(|(k, _)| {
                        k.contains("missed")
                            || k.contains("dropped")
                            || k.contains("rejected")
                            || k.contains("late")
                            || k.contains("restarts")
                            || k.contains("repeated")
                            || k.contains("recovered")
                    })
                    .map(move |(k, v)| format!("{} {k} {v}", st.stage))
            })
            .collect();
        s += &format!("  mirror {} drops: {}\n", r.mirror, counters.join(", "));
    }
    s
}

/// Where the CPU went, per stage: each step's CPU time on its thread, and
/// the process's CPU over its run as a share of one core.
pub fn cpu_table(results: &[PlacementResult]) -> String {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut s = format!(
        "\nCPU per stage: thread CPU per step, ms; process CPU as a share of one core ({cores} cores); \
         how the kernel scheduled it\n"
    );
    s += &format!(
        "  {:<10} {:<16} {:>7} {:>8} {:>8} {:>11}  {}\n",
        "placement", "stage", "steps", "median", "p99", "core share", "scheduling"
    );
    for r in results {
        let mut total = 0.0;
        for stage in &r.stages {
            let Some(cpu) = &stage.cpu else { continue };
            let (steps, median, p99) = cpu.per_step.as_ref().map_or(
                ("-".to_string(), "-".to_string(), "-".to_string()),
                |p| {
                    (
                        p.count.to_string(),
                        format!("{:.2}", p.p50_ms),
                        format!("{:.2}", p.p99_ms),
                    )
                },
            );
            total += cpu.core_share;
            let scheduling = cpu
                .scheduling
                .as_ref()
                .map_or("-".to_string(), ToString::to_string);
            s += &format!(
                "  {:<10} {:<16} {:>7} {:>8} {:>8} {:>9.1} %  {}\n",
                format!("mirror {}", r.mirror),
                stage.stage,
                steps,
                median,
                p99,
                100.0 * cpu.core_share,
                scheduling
            );
        }
        s += &format!(
            "  {:<10} {:<16} {:>7} {:>8} {:>8} {:>9.1} %\n",
            format!("mirror {}", r.mirror),
            "all stages",
            "",
            "",
            "",
            100.0 * total
        );
    }
    s
}

pub fn table(results: &[PlacementResult], method: Method) -> String {
    let mut s = format!(
        "Live pipeline, method {method}: mean errors on the test poses of each placement\n"
    );
    s += &format!(
        "  {:<30} {:>12} {:>12} {:>12} {:>12} {:>10} {:>10} {:>10} {:>10}\n",
        "",
        "mirror 3D mm",
        "direct 3D mm",
        "mirror 2D px",
        "direct 2D px",
        "plane deg",
        "±1σ deg",
        "object mm",
        "±1σ mm"
    );
    let p = PAPER_FIGURES;
    s += &format!(
        "  {:<30} {:>12.2} {:>12.2} {:>12.2} {:>12.2} {:>10} {:>10} {:>10} {:>10}\n",
        "Hart & Scassellati 2012 (Nico)",
        p.mirror_3d_mm,
        p.direct_3d_mm,
        p.mirror_2d_px,
        p.direct_2d_px,
        "-",
        "-",
        "-",
        "-"
    );
    let mut sums = [0.0; 8];
    let mut counts = [0usize; 8];
    for r in results {
        let (Some(report), Some(truth)) = (&r.report, &r.truth) else {
            continue;
        };
        let e = report.evaluation.as_ref();
        let values = [
            e.and_then(|e| e.mirror_3d_mm),
            e.and_then(|e| e.direct_3d_mm),
            e.and_then(|e| e.mirror_2d_px),
            e.and_then(|e| e.direct_2d_px),
            truth.plane_angle_deg,
            truth.plane_angle_sigma_deg,
            truth.hidden_object_error_mm,
            truth.hidden_object_sigma_mm,
        ];
        for (i, v) in values.iter().enumerate() {
            if let Some(v) = v {
                sums[i] += v;
                counts[i] += 1;
            }
        }
        s += &format!(
            "  {:<30} {:>12} {:>12} {:>12} {:>12} {:>10} {:>10} {:>10} {:>10}   ({} train / {} test samples)\n",
            format!("mirror placement {}", r.mirror),
            cell(values[0]),
            cell(values[1]),
            cell(values[2]),
            cell(values[3]),
            fine(values[4]),
            fine(values[5]),
            cell(values[6]),
            cell(values[7]),
            report.train_samples,
            report.test_samples
        );
    }
    let mean = |i: usize| (counts[i] > 0).then(|| sums[i] / counts[i] as f64);
    s += &format!(
        "  {:<30} {:>12} {:>12} {:>12} {:>12} {:>10} {:>10} {:>10} {:>10}\n",
        "mean",
        cell(mean(0)),
        cell(mean(1)),
        cell(mean(2)),
        cell(mean(3)),
        fine(mean(4)),
        fine(mean(5)),
        cell(mean(6)),
        cell(mean(7))
    );
    s
}
