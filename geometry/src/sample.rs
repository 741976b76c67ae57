//! One observation of the end-effector marker: a row of the samples file.

use nalgebra::{Vector2, Vector3};

/// Whether the marker was seen in the mirror or directly.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum View {
    /// Seen as a reflection in the mirror.
    Mirror,
    /// Seen directly by the cameras.
    Direct,
}

impl View {
    /// The name used in files.
    pub fn as_str(self) -> &'static str {
        match self {
            View::Mirror => "mirror",
            View::Direct => "direct",
        }
    }
}

/// One arm pose and what both cameras saw of the marker.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Pose identifier.
    pub pose: u64,
    /// Mirror or direct view.
    pub view: View,
    /// Joint angles as read from the encoders, if known.
    pub joints: Option<Vec<f64>>,
    /// The end-effector model's prediction `J`, if given instead of joints.
    pub model_point: Option<Vector3<f64>>,
    /// Raw (distorted) pixel coordinates of the marker centre, left then right.
    pub pixels: [Vector2<f64>; 2],
}
