//! What the simulated head sees, drawn with real ArUco marker images: the
//! renderer ([`render`]), the still scene ([`room`]), the camera's sensor
//! ([`sensor`]) and what the images look like ([`look::Look`]).
//!
//! A library of its own so that the camera stage, the tracker's and the
//! recorder's benchmarks and the tests draw frames without importing a stage.
//!
//! ```no_run
//! use renderer::Renderer;
//! use geometry::sim::{Facing, SimWorld};
//! let world = SimWorld::nico(0)?;
//! let mut renderer = Renderer::new(world)?;
//! let (mut left, mut right) = (vec![0u8; 640 * 480], vec![0u8; 640 * 480]);
//! renderer.render(&[0.8, 0.1, 0.2, -0.4], Facing::Mirror, 1, &mut left, &mut right)?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod look;
pub mod render;
pub mod room;
pub mod sensor;

pub use render::{RenderTruth, Renderer};

/// Why a frame or a renderer could not be made.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// OpenCV failed (drawing a marker, a warp, a blur, JPEG coding).
    #[error(transparent)]
    OpenCv(#[from] opencv::Error),
    /// A point could not be projected.
    #[error(transparent)]
    Geometry(#[from] geometry::GeometryError),
    /// A look parameter is out of range (its name).
    #[error("look parameter {0} is out of range")]
    BadLook(&'static str),
    /// A card's marker id is not in the dictionary the cards are drawn from.
    #[error("marker id {0} is not in DICT_4X4_50")]
    UnknownMarker(u32),
    /// The simulated world has no arm to draw.
    #[error("the simulated world has no arm")]
    NoArm,
    /// A drawing thread panicked.
    #[error("drawing the {0} view panicked")]
    Panicked(&'static str),
    /// A broken invariant of the renderer's own (a bug).
    #[error("renderer: {0}")]
    Internal(&'static str),
}

/// The renderer's results.
pub type Result<T, E = RenderError> = std::result::Result<T, E>;
