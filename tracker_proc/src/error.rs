//! The library's one error type.

use std::path::PathBuf;

/// Why detection, tracking or loading the real-image set failed.
///
/// A frame that does not match its header or is stamped out of order is
/// no error: [`crate::Tracker::step`] answers it with
/// [`crate::Tracked::Rejected`] and counts it.
#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    /// An OpenCV call failed (a warp, a threshold, a `Mat` view of a frame's
    /// pixels, a dictionary lookup).
    #[error(transparent)]
    OpenCv(#[from] opencv::Error),
    /// OpenCV's `detectMarkers` pass failed.
    #[error("ArUco detection")]
    Detection(#[source] opencv::Error),
    /// A frame's payload could not be split into its two images.
    #[error("frame {seq}: {reason}")]
    BadFrame {
        /// The frame's sequence number.
        seq: u64,
        /// What is wrong with it.
        reason: String,
    },
    /// The thread searching the right camera's image panicked.
    #[error("the right camera's {task} panicked")]
    Panicked {
        /// What the thread was doing: `detection` or `full scan`.
        task: &'static str,
    },
    /// The real-image set's file could not be read.
    #[error("reading {}", path.display())]
    ReadSet {
        /// The set's `set.json`.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// The real-image set's file is not the JSON `real_markers.py` writes.
    #[error("parsing {}", path.display())]
    ParseSet {
        /// The set's `set.json`.
        path: PathBuf,
        /// The cause.
        #[source]
        source: serde_json::Error,
    },
}

/// The library's results.
pub type Result<T, E = TrackError> = std::result::Result<T, E>;
