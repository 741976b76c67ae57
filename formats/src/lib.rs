//! The project's file formats, a contract with users (documented in the README):
//!
//! - [`rig`]: the robot's cameras and arm, TOML;
//! - [`camera_file`]: camera calibration files (ROS `camera_info`, OpenCV YAML);
//! - [`samples`]: observed marker positions per pose, CSV;
//! - [`calibration`]: a mirror calibration, JSON;
//! - [`evaluation`]: the paper's error metrics, JSON;
//! - [`export`]: a calibration in standard forms (transforms JSON, Foxglove `FrameTransforms`, corrected DH);
//! - [`plan`]: the pose plan the arm is driven through, CSV;
//! - [`urdf`]: robot descriptions, the arm's chain from a URDF.
//!
//! Every reader reports a bad file as a [`FormatError`] whose one-line
//! message names the file and the line or key at fault.
//!
//! ```no_run
//! let rig = formats::rig::read("rig.toml")?;
//! let samples = formats::samples::read("train.csv", rig.arm.as_ref().map(|a| a.dof()))?;
//! # Ok::<(), formats::FormatError>(())
//! ```

pub mod calibration;
pub mod camera_file;
pub mod evaluation;
pub mod export;
pub mod plan;
pub mod rig;
pub mod samples;
pub mod urdf;

use std::fmt;
use std::path::Path;

/// A file that could not be read, parsed or validated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct FormatError {
    /// The file.
    pub path: String,
    /// Where in it (`line 7`, `key camera[0].fx`), if known.
    pub location: Option<String>,
    /// What is wrong, on one line.
    pub message: String,
}

impl fmt::Display for FormatError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.location {
            Some(at) => write!(f, "{}: {}: {}", self.path, at, self.message),
            None => write!(f, "{}: {}", self.path, self.message),
        }
    }
}

impl FormatError {
    pub(crate) fn new(path: &Path, location: Option<String>, message: impl Into<String>) -> Self {
        // Keep the message on one line whatever the underlying parser says.
        let message: String = message.into();
        let message = message.split_whitespace().collect::<Vec<_>>().join(" ");
        Self {
            path: path.display().to_string(),
            location,
            message,
        }
    }

    pub(crate) fn at_key(path: &Path, key: impl fmt::Display, message: impl Into<String>) -> Self {
        Self::new(path, Some(format!("key {key}")), message)
    }
}

/// The text of the file at `path`, or an error naming it.
pub fn read_text(path: &Path) -> Result<String, FormatError> {
    std::fs::read_to_string(path)
        .map_err(|e| FormatError::new(path, None, format!("cannot read: {e}")))
}

pub(crate) fn write_text(path: &Path, text: &str) -> Result<(), FormatError> {
    std::fs::write(path, text)
        .map_err(|e| FormatError::new(path, None, format!("cannot write: {e}")))
}

/// A row-major 3x3 matrix from 9 numbers.
pub(crate) fn mat3(v: &[f64; 9]) -> nalgebra::Matrix3<f64> {
    nalgebra::Matrix3::from_row_slice(v)
}

/// 16 numbers, row-major, from a rigid transform (a rig's or a
/// calibration's `world_from_base`).
pub(crate) fn pose_row_major(pose: &nalgebra::Isometry3<f64>) -> [f64; 16] {
    let m = pose.to_homogeneous();
    std::array::from_fn(|i| m[(i / 4, i % 4)])
}

/// The rigid transform in 16 row-major numbers at `key` of `path`: finite,
/// last row `0, 0, 0, 1`, a proper rotation.
pub(crate) fn parse_pose(
    path: &Path,
    key: &str,
    v: &[f64; 16],
) -> Result<nalgebra::Isometry3<f64>, FormatError> {
    check_finite(path, key, v)?;
    let m = nalgebra::Matrix4::from_row_slice(v);
    if (m.row(3) - nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0)).norm() > 1e-9 {
        return Err(FormatError::at_key(
            path,
            key,
            "last row must be [0, 0, 0, 1]",
        ));
    }
    let r = m.fixed_view::<3, 3>(0, 0).into_owned();
    check_rotation(path, key, &r, false)?;
    Ok(nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
        nalgebra::UnitQuaternion::from_rotation_matrix(
            &nalgebra::Rotation3::from_matrix_unchecked(r),
        ),
    ))
}

/// 9 numbers, row-major, from a 3x3 matrix.
pub(crate) fn mat3_row_major(m: &nalgebra::Matrix3<f64>) -> [f64; 9] {
    let mut out = [0.0; 9];
    for r in 0..3 {
        for c in 0..3 {
            out[3 * r + c] = m[(r, c)];
        }
    }
    out
}

/// Checks that `m` is a rotation (orthonormal), proper or (if allowed) improper.
pub(crate) fn check_rotation(
    path: &Path,
    key: &str,
    m: &nalgebra::Matrix3<f64>,
    allow_improper: bool,
) -> Result<(), FormatError> {
    if !m.iter().all(|v| v.is_finite()) {
        return Err(FormatError::at_key(
            path,
            key,
            "contains a non-finite number",
        ));
    }
    let err = (m * m.transpose() - nalgebra::Matrix3::identity()).norm();
    if err > 1e-6 {
        return Err(FormatError::at_key(
            path,
            key,
            format!("is not a rotation matrix (|R R^T - I| = {err:.3e})"),
        ));
    }
    if !allow_improper && m.determinant() < 0.0 {
        return Err(FormatError::at_key(
            path,
            key,
            "has determinant -1; expected a proper rotation",
        ));
    }
    Ok(())
}

pub(crate) fn check_finite(path: &Path, key: &str, values: &[f64]) -> Result<(), FormatError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(FormatError::at_key(
            path,
            key,
            "contains a non-finite number",
        ))
    }
}
