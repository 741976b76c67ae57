//! Geometry of a stereo robot looking at itself in a planar mirror.
//!
//! Everything here is plain math on [`nalgebra`] types: no IPC, no OpenCV, no
//! file formats. Units are millimetres, radians and pixels; the world frame is
//! the robot's egocentric (stereo head) frame.
//!
//! - [`camera`]: pinhole camera `P = K [R | -R C]` with lens distortion.
//! - [`distortion`]: OpenCV's distortion model (`plumb_bob` and `rational_polynomial`).
//! - [`triangulate`]: stereo triangulation (linear DLT refined on reprojection error).
//! - [`kinematics`]: forward kinematics from a DH table or a general (URDF) chain.
//! - [`plane`]: planes, reflections and the exact mirror-perspective camera.
//! - [`lsq`]: a thin adapter over the `levenberg-marquardt` crate.
//! - [`sim`]: a seeded simulator of Nico-like datasets with ground truth, and the
//!   simulated world the camera renders ([`sim::SimWorld`]).
//!
//! ```
//! use geometry::{camera::{Camera, Intrinsics}, plane::Plane};
//! use nalgebra::{Matrix3, Vector3};
//!
//! let cam = Camera::new(Intrinsics::ideal(640, 480, 550.0), Matrix3::identity(), Vector3::zeros());
//! let mirror = Plane::new(Vector3::new(0.0, 0.0, -1.0), 500.0).unwrap();
//! let virtual_cam = mirror.mirror_camera(&cam);
//! // A point in front of the mirror projects through the mirror camera where
//! // its reflection projects through the real camera.
//! let p = Vector3::new(40.0, -20.0, 300.0);
//! let a = virtual_cam.project(&p).unwrap();
//! let b = cam.project(&mirror.reflect_point(&p)).unwrap();
//! assert!((a - b).norm() < 1e-9);
//! ```

pub mod camera;
pub mod distortion;
pub mod kinematics;
pub mod lsq;
pub mod plane;
pub mod register;
pub mod rig;
pub mod sample;
pub mod sim;
pub mod triangulate;

pub use camera::{Camera, Intrinsics};
pub use distortion::{Distortion, DistortionModel};
pub use kinematics::{
    Arm, ArmModel, Chain, ChainJoint, ChainSource, DhJoint, JointInfo, JointKind, JointValue,
};
pub use plane::Plane;
pub use rig::Rig;
pub use sample::{Role, Sample, View};

/// Implements `TryFrom<u32>` for a `#[repr(u32)]` enum with an `ALL` list
/// of its variants: the variant whose discriminant is the value, or the
/// value back as the error. For enums that travel as `u32` wire fields.
#[macro_export]
macro_rules! try_from_u32 {
    ($t:ty) => {
        impl TryFrom<u32> for $t {
            type Error = u32;
            fn try_from(value: u32) -> Result<Self, u32> {
                <$t>::ALL
                    .into_iter()
                    .find(|v| *v as u32 == value)
                    .ok_or(value)
            }
        }
    };
}

/// Errors of the geometry library.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeometryError {
    /// A point lies (numerically) in the plane through the camera centre parallel to the image.
    #[error("point has zero depth in the camera (it lies in the camera's focal plane)")]
    ZeroDepth,
    /// Iterative undistortion did not converge.
    #[error("undistortion did not converge for pixel ({u:.3}, {v:.3})")]
    UndistortDiverged {
        /// Pixel column.
        u: f64,
        /// Pixel row.
        v: f64,
    },
    /// A number that must be finite is not.
    #[error("non-finite value in {0}")]
    NonFinite(&'static str),
    /// The input does not determine the quantity asked for.
    #[error("degenerate input: {0}")]
    Degenerate(String),
    /// A simulated mirror placement that the scene does not have.
    #[error("mirror placement {placement} does not exist (the scene has {placements})")]
    NoSuchMirror {
        /// The placement asked for.
        placement: usize,
        /// How many the scene has.
        placements: usize,
    },
}
