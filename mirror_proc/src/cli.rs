//! The offline command line: `calibrate`, `evaluate`, `simulate`, `experiment`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, anyhow, bail};
use clap::{Parser, Subcommand, ValueEnum};
use geometry::sim::{self, Counts, NoiseModel};

use mirror_proc::calibrate::{
    CalibrateError, CalibrateOptions, Estimate, Fit, Method, calibrate_placements,
};
use mirror_proc::evaluate::evaluate;
use mirror_proc::experiment::{self, ExperimentConfig};
use mirror_proc::plot;

/// Mirror perspective-taking: calibrate a robot's mirror-perspective cameras
/// from views of its own end-effector in a mirror, and evaluate them.
#[derive(Debug, Parser)]
#[command(name = "mirror_proc", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Estimate the mirror-perspective cameras from mirror-view samples.
    Calibrate {
        /// Rig file (TOML): cameras and arm.
        #[arg(long)]
        rig: PathBuf,
        /// Training samples (CSV). Give it once per mirror placement: one
        /// plane each, the cameras and the arm shared. Direct-view rows
        /// constrain the arm when it is modelled (joint+kinematics, or
        /// --estimate).
        #[arg(long, required = true)]
        samples: Vec<PathBuf>,
        /// Estimate the arm's base (world_from_base, 6 DOF) and/or tool (the
        /// marker point, 3) too: base, tool or base,tool. The base needs
        /// direct views or three placements.
        #[arg(long, value_name = "LIST", default_value = "none")]
        estimate: String,
        /// paper | joint | joint+kinematics (needs joint angles in the samples).
        #[arg(long, default_value = "joint+kinematics")]
        method: String,
        /// Where to write the calibration (JSON); stdout if absent.
        #[arg(long)]
        out: Option<PathBuf>,
        /// The detections' noise, px per coordinate (1 sigma), that the fit
        /// is judged against [default: the rig's pixel_sigma, else 0.2, our
        /// tracker's].
        #[arg(long, value_name = "PX")]
        pixel_sigma: Option<f64>,
    },
    /// Print the paper's error metrics (JSON) of a calibration on test samples.
    Evaluate {
        /// Rig file (TOML).
        #[arg(long)]
        rig: PathBuf,
        /// Calibration file (JSON).
        #[arg(long)]
        calibration: PathBuf,
        /// Test samples (CSV), mirror and/or direct views.
        #[arg(long)]
        samples: PathBuf,
        /// For a calibration across several placements, the placement the
        /// samples' mirror views are of (0 is the first --samples file).
        #[arg(long, default_value_t = 0)]
        placement: usize,
    },
    /// Write a simulated rig, training and test samples, and the ground truth.
    Simulate {
        /// Scene preset.
        #[arg(long, value_enum, default_value_t = Preset::Nico)]
        preset: Preset,
        /// Mirror placement (0, 1 or 2).
        #[arg(long, default_value_t = 0)]
        mirror: usize,
        /// Take the robot's cameras and arm from this rig file instead of
        /// the preset's; the preset's mirror placements are kept.
        #[arg(long)]
        rig: Option<PathBuf>,
        /// Output directory (created): rig.toml, train.csv, test.csv, truth.json.
        #[arg(long)]
        out: PathBuf,
        /// Noise: the preset's, or none.
        #[arg(long, value_enum, default_value_t = Noise::Preset)]
        noise: Noise,
        /// Simulator seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Mirror-view training poses.
        #[arg(long, default_value_t = 50)]
        train: usize,
        /// Mirror-view test poses.
        #[arg(long, default_value_t = 100)]
        test: usize,
        /// Direct-view test poses (appended to test.csv).
        #[arg(long, default_value_t = 100)]
        direct: usize,
    },
    /// The live stage: pair joint states with detections, calibrate as samples
    /// arrive, publish calibrations, predictions and located objects.
    Run(stages::mirror::Args),
    /// Write a calibration in standard forms: the mirror as transforms JSON
    /// and a Foxglove FrameTransforms snapshot, and the calibrated arm as a
    /// corrected URDF (or DH table) with its rig.
    Export {
        /// Rig file (TOML) the calibration was made with.
        #[arg(long)]
        rig: PathBuf,
        /// Calibration file (JSON).
        #[arg(long)]
        calibration: PathBuf,
        /// Output directory (created).
        #[arg(long)]
        out: PathBuf,
    },
    /// Run the paper's experiment on the simulated robot and print its table.
    Experiment {
        /// Scene preset.
        #[arg(long, value_enum, default_value_t = Preset::Nico)]
        preset: Preset,
        /// Take the robot's cameras and arm from this rig file instead of
        /// the preset's; the preset's mirror placements are kept.
        #[arg(long)]
        rig: Option<PathBuf>,
        /// Write every figure as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Draw the learning curves here (.svg).
        #[arg(long)]
        plot: Option<PathBuf>,
        /// A small run for tests: sizes 3, 5, 10, 20 and 30 test poses per placement.
        #[arg(long)]
        quick: bool,
        /// Noise: the preset's, or none.
        #[arg(long, value_enum, default_value_t = Noise::Preset)]
        noise: Noise,
        /// Simulator seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum Preset {
    /// The Nico-like robot of the paper.
    Nico,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum Noise {
    /// The preset's pixel noise and encoder offsets.
    Preset,
    /// No noise at all.
    None,
}

fn noise_model(noise: Noise, dof: usize) -> NoiseModel {
    match noise {
        Noise::Preset => sim::nico_noise_for(dof),
        Noise::None => NoiseModel::none(dof),
    }
}

/// The preset's scene, with the robot of `rig` if given.
fn scene(rig: Option<&Path>) -> Result<sim::Scene> {
    let mut scene = sim::nico_scene();
    if let Some(path) = rig {
        let rig = read_rig(path)?;
        if rig.arm.is_none() {
            bail!(
                "{}: the rig has no [arm]; the simulator moves the arm",
                path.display()
            );
        }
        scene.rig = rig;
    }
    Ok(scene)
}

/// Parses the arguments, runs, and maps any error to one line and exit code 1
/// (2 for usage errors).
pub fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !e.use_stderr() => {
            // --help, --version
            print!("{e}");
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            let text = e.to_string();
            let first = text.lines().next().unwrap_or("invalid arguments");
            eprintln!("mirror_proc: {}", first.trim_start_matches("error: "));
            return ExitCode::from(2);
        }
    };
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("mirror_proc: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// A calibration error with the samples file it concerns named: the one
/// file, or the placement's among several.
fn name_samples_file(e: CalibrateError, files: &[PathBuf]) -> anyhow::Error {
    match e {
        CalibrateError::InPlacement { placement, source } => {
            let file = files.get(placement).map_or_else(
                || format!("placement {placement}"),
                |f| f.display().to_string(),
            );
            anyhow!("{file}: {source}")
        }
        // Errors of the whole set (what cannot be estimated) name no file.
        e @ CalibrateError::CannotEstimate { .. } => anyhow!(e),
        e if files.len() == 1 => anyhow!("{}: {e}", files[0].display()),
        e => anyhow!(e),
    }
}

fn read_rig(path: &Path) -> Result<geometry::Rig> {
    Ok(formats::rig::read(path)?)
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Calibrate {
            rig,
            samples,
            estimate,
            method,
            out,
            pixel_sigma,
        } => {
            let method: Method = method.parse().map_err(|e| anyhow!("--method: {e}"))?;
            let estimate: Estimate = estimate.parse().map_err(|e| anyhow!("--estimate: {e}"))?;
            if let Some(sigma) = pixel_sigma
                && !(sigma.is_finite() && sigma > 0.0)
            {
                bail!("--pixel-sigma: must be a positive number of pixels, found {sigma}");
            }
            let rig_model = read_rig(&rig)?;
            let dof = rig_model.arm.as_ref().map(|a| a.dof());
            let data = samples
                .iter()
                .map(|path| formats::samples::read(path, dof))
                .collect::<Result<Vec<_>, _>>()?;
            let placements: Vec<&[geometry::Sample]> = data.iter().map(Vec::as_slice).collect();
            let options = CalibrateOptions {
                pixel_sigma,
                ..CalibrateOptions::default()
            };
            let cal = calibrate_placements(&rig_model, &placements, method, estimate, options)
                .map_err(|e| name_samples_file(e, &samples))?;
            if let Fit::Poor { cause } = &cal.fit {
                eprintln!("mirror_proc: warning: poor fit: {cause}");
            }
            let json = cal.to_file(&rig_model).to_json();
            match out {
                Some(path) => std::fs::write(&path, json)
                    .with_context(|| format!("{}: cannot write", path.display()))?,
                None => print!("{json}"),
            }
        }
        Command::Evaluate {
            rig,
            calibration,
            samples,
            placement,
        } => {
            let rig_model = read_rig(&rig)?;
            let dof = rig_model.arm.as_ref().map(|a| a.dof());
            let cal = formats::calibration::read(&calibration)?;
            cal.check_arm(&calibration, &rig_model)?;
            // The arm as calibrated: its estimated base and tool, if any.
            let rig_model = cal.corrected_rig(&calibration, &rig_model)?;
            let cameras = cal
                .placement_cameras(&rig_model, placement)
                .ok_or_else(|| {
                    anyhow!(
                        "--placement: {}: the calibration has {} placement(s)",
                        placement,
                        cal.placements.len().max(1)
                    )
                })?;
            let data = formats::samples::read(&samples, dof)?;
            let errors = evaluate(&rig_model, &cameras, cal.nonzero_joint_offsets(), &data)
                .with_context(|| format!("{}", samples.display()))?;
            print!("{}", errors.summary().to_json());
        }
        Command::Simulate {
            preset: Preset::Nico,
            mirror,
            rig,
            out,
            noise,
            seed,
            train,
            test,
            direct,
        } => {
            let scene = scene(rig.as_deref())?;
            if mirror >= scene.mirrors.len() {
                bail!(
                    "--mirror: placement {mirror} does not exist (0..={})",
                    scene.mirrors.len() - 1
                );
            }
            let dof = scene.rig.arm.as_ref().map_or(0, |a| a.dof());
            let counts = Counts {
                train,
                test,
                direct,
            };
            let data = sim::generate(&scene, mirror, &noise_model(noise, dof), counts, seed)?;
            std::fs::create_dir_all(&out)
                .with_context(|| format!("{}: cannot create", out.display()))?;
            formats::rig::write(out.join("rig.toml"), &data.rig)?;
            formats::samples::write(out.join("train.csv"), &data.train)?;
            let test_samples: Vec<_> = data.test.iter().chain(&data.direct).cloned().collect();
            formats::samples::write(out.join("test.csv"), &test_samples)?;
            let truth = formats::calibration::CalibrationFile::new(
                "truth",
                Some(&data.truth.mirror.plane),
                &data.rig.names,
                &data.truth.mirror_cameras,
                Some(&data.truth.joint_offsets),
                0.0,
                0,
            )
            .with_joint_names(&data.rig);
            formats::calibration::write(out.join("truth.json"), &truth)?;
            println!(
                "wrote {}/{{rig.toml, train.csv ({train} mirror poses), test.csv ({test} mirror + {direct} direct poses), truth.json}}",
                out.display()
            );
        }
        Command::Export {
            rig,
            calibration,
            out,
        } => {
            for path in mirror_proc::export::export(&rig, &calibration, &out)? {
                println!("wrote {}", path.display());
            }
        }
        Command::Run(stages::mirror::Args {
            prefix,
            rig,
            method,
            min_train,
            settle_ms,
            report,
            journal,
            no_drift_watch,
        }) => {
            let rig_model = read_rig(&rig)?;
            let config = mirror_proc::live::LiveConfig {
                method,
                min_train,
                settle_margin_ns: settle_ms * 1_000_000,
                watch_drift: !no_drift_watch,
                ..Default::default()
            };
            let result =
                mirror_proc::live_loop::run(&prefix, rig_model, config, journal.as_deref())?;
            let text = serde_json::to_string_pretty(&result)? + "\n";
            match report {
                Some(path) => std::fs::write(&path, text)
                    .with_context(|| format!("{}: cannot write", path.display()))?,
                None => print!("{text}"),
            }
        }
        Command::Experiment {
            preset: Preset::Nico,
            rig,
            json,
            plot: plot_path,
            quick,
            noise,
            seed,
        } => {
            let scene = scene(rig.as_deref())?;
            let dof = scene.rig.arm.as_ref().map_or(0, |a| a.dof());
            let noise = noise_model(noise, dof);
            let config = if quick {
                ExperimentConfig::quick("nico", noise, seed)
            } else {
                ExperimentConfig::paper("nico", noise, seed)
            };
            let started = std::time::Instant::now();
            let result = experiment::run(&scene, &config, |m| {
                eprintln!(
                    "mirror placement {m} done ({:.1} s)",
                    started.elapsed().as_secs_f64()
                );
            })?;
            print!("{}", experiment::table(&result));
            if let Some(path) = json {
                let text = serde_json::to_string_pretty(&result)? + "\n";
                std::fs::write(&path, text)
                    .with_context(|| format!("{}: cannot write", path.display()))?;
                println!("figures: {}", path.display());
            }
            if let Some(path) = plot_path {
                plot::learning_curves(&result, &path)?;
                println!("plot: {}", path.display());
            }
        }
    }
    Ok(())
}
