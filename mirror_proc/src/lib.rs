//! The mirror stage: estimating mirror-perspective cameras, evaluating them
//! with the paper's metrics, reproducing the paper's experiment, exporting a
//! calibration, and the live stage's loop. The offline command line
//! (`mirror_proc calibrate | evaluate | simulate | experiment | export | run`)
//! is the crate's binary.
//!
//! ```
//! use geometry::sim::{generate, nico_scene, NoiseModel, Counts};
//! use mirror_proc::calibrate::{calibrate, Method};
//!
//! let scene = nico_scene();
//! let data = generate(&scene, 0, &NoiseModel::none(4), Counts { train: 10, test: 0, direct: 0 }, 1).unwrap();
//! let cal = calibrate(&data.rig, &data.train, Method::Joint).unwrap();
//! let truth = data.truth.mirror_cameras[0].center;
//! assert!((cal.mirror_cameras[0].center - truth).norm() < 1e-6);
//! ```

pub mod calibrate;
pub mod drift;
pub mod epochs;
pub mod evaluate;
pub mod experiment;
pub mod export;
pub mod live;
pub mod live_loop;
pub mod plot;
pub mod still;
