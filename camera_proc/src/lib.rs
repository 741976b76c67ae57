//! The camera stage: readers of real footage ([`source`]), the frame
//! schedule ([`clock`]), the loops that publish frames, rendered by the
//! `renderer` crate or read from a source ([`stage`]), and a snapshot of
//! the simulated scene for debugging ([`snapshot`]). Their failures are
//! [`CameraError`]s.

pub mod clock;
pub mod snapshot;
pub mod source;
pub mod stage;

use std::path::PathBuf;

use geometry::GeometryError;
use renderer::RenderError;
use runtime::BusError;

/// Why a source, the camera stage or a snapshot failed.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The shared-memory bus failed (opening a port, waiting for
    /// subscribers, receiving, publishing).
    #[error(transparent)]
    Bus(#[from] BusError),
    /// OpenCV failed (opening or reading a capture, decoding, converting).
    #[error(transparent)]
    OpenCv(#[from] opencv::Error),
    /// The renderer could not be made or could not draw a frame.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// The simulated world could not be made (a mirror placement it does
    /// not have).
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    /// A directory of image pairs could not be listed.
    #[error("{}: cannot list", dir.display())]
    List {
        /// The directory.
        dir: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// A left image of a directory of pairs has no right image beside it.
    #[error("{}: no matching right image {}", left.display(), right.display())]
    NoRightImage {
        /// The left image.
        left: PathBuf,
        /// The right image it should have.
        right: PathBuf,
    },
    /// A directory of pairs holds no left image.
    #[error("{}: no `*left*` images", dir.display())]
    NoLeftImages {
        /// The directory.
        dir: PathBuf,
    },
    /// An image file that OpenCV cannot decode.
    #[error("{}: cannot decode", path.display())]
    Undecodable {
        /// The image.
        path: PathBuf,
    },
    /// An image of a directory of pairs whose size differs from the first
    /// pair's.
    #[error("{}: size {width}x{height} differs from the first pair's", path.display())]
    SizeDiffers {
        /// The image.
        path: PathBuf,
        /// Its width, px.
        width: i32,
        /// Its height, px.
        height: i32,
    },
    /// A decoded image with a number of channels other than 1, 3 or 4.
    #[error("{what}: {channels} channels not supported")]
    Channels {
        /// The image or capture.
        what: String,
        /// Its channels.
        channels: i32,
    },
    /// A decoded image whose size is not the source's.
    #[error("{what}: image has {bytes} bytes, expected {expected}")]
    ImageBytes {
        /// The image or capture.
        what: String,
        /// Its bytes as mono8.
        bytes: usize,
        /// The bytes of one image of the source.
        expected: usize,
    },
    /// A video file or device that does not open.
    #[error("{capture}: cannot open")]
    CannotOpen {
        /// The file or device.
        capture: String,
    },
    /// A side-by-side capture whose width does not split into two images.
    #[error("{capture}: {width} px wide, not two side-by-side images")]
    NotSideBySide {
        /// The file or device.
        capture: String,
        /// Its frame width, px.
        width: u32,
    },
    /// Two cameras whose frame sizes differ.
    #[error(
        "{right}: {}x{} px, the left camera {left} gives {}x{}",
        right_size.0,
        right_size.1,
        left_size.0,
        left_size.1
    )]
    PairSizes {
        /// The left device or file.
        left: String,
        /// The right device or file.
        right: String,
        /// The left frames' width and height, px.
        left_size: (u32, u32),
        /// The right frames' width and height, px.
        right_size: (u32, u32),
    },
    /// A frame rate outside (0, 1000] Hz.
    #[error("--fps must be in (0, 1000]")]
    BadFps {
        /// The rate asked for, Hz.
        fps: f64,
    },
    /// A snapshot's joint angles do not match the simulated arm.
    #[error("--q: {given} joint angles given, the arm has {dof}")]
    JointCount {
        /// Joint angles given.
        given: usize,
        /// The arm's joints.
        dof: usize,
    },
    /// An image could not be written.
    #[error("{}: cannot write", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// OpenCV's error.
        #[source]
        source: opencv::Error,
    },
}
