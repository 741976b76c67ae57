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

/// What a planned pose is for. The discriminants are the wire and
/// recording values (`role` fields of the messages): never reorder them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum Role {
    /// Calibration (training) pose, seen in the mirror.
    Train = 0,
    /// Test pose, seen in the mirror.
    Test = 1,
    /// Test pose, seen directly.
    Direct = 2,
}

impl Role {
    /// Every role.
    pub const ALL: [Role; 3] = [Role::Train, Role::Test, Role::Direct];

    /// The name used in files (`train`, `test`, `direct`).
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Train => "train",
            Role::Test => "test",
            Role::Direct => "direct",
        }
    }

    /// The role with this name in files.
    pub fn from_name(name: &str) -> Option<Role> {
        Role::ALL.into_iter().find(|r| r.as_str() == name)
    }

    /// How the marker is seen at a pose of this role.
    pub fn view(self) -> View {
        match self {
            Role::Direct => View::Direct,
            Role::Train | Role::Test => View::Mirror,
        }
    }
}

crate::try_from_u32!(Role);

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
