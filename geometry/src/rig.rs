//! The robot's calibrated stereo head and (optionally) its arm model.

use crate::{Arm, Camera};

/// A calibrated stereo rig: left and right camera, and the arm's DH model.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    /// Camera names, left then right.
    pub names: [String; 2],
    /// Left and right cameras.
    pub cameras: [Camera; 2],
    /// The arm's kinematic model, if the rig describes one.
    pub arm: Option<Arm>,
    /// The detections' noise, px per coordinate (1 sigma), when the rig
    /// states it: what a fit's residuals are judged against.
    pub pixel_sigma: Option<f64>,
}

impl Rig {
    /// Both cameras as references, the shape the triangulation takes.
    pub fn camera_refs(&self) -> [&Camera; 2] {
        [&self.cameras[0], &self.cameras[1]]
    }
}
