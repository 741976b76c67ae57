//! What secures a zenoh link between hosts, for the bridge of a split run
//! and for the ROS 2 stages' link to a router:
//!
//! - [`certs`]: the run's CA and each side's certificate (`pipeline certs`);
//! - [`tls`]: a side's identity, as the zenoh settings of mutual TLS;
//! - [`endpoint`]: which endpoints need certificates, and which are plain
//!   TCP open to a network (refused unless the user says `--insecure`).
//!
//! Who may publish and subscribe what is the bridge's to say (its access
//! control follows from what it sends and receives); this crate knows only
//! who is at the other end.

pub mod certs;
pub mod endpoint;
pub mod tls;

use std::path::{Path, PathBuf};

/// Why a link cannot be set up as asked.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// `pipeline certs` would replace the CA whose certificates are in use.
    #[error(
        "{} exists: a new CA would stop the certificates made with it from working; give --force to replace it",
        .0.display()
    )]
    CaExists(PathBuf),
    /// A certificate could not be made.
    #[error("making certificates: {0}")]
    Certificate(String),
    /// An endpoint the link may not use as given.
    #[error("endpoint {0}: {1}")]
    Endpoint(String, String),
    /// A certificate or key file that is missing, unreadable or open to
    /// others.
    #[error("{}: {why}", .path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        why: String,
    },
    /// Zenoh refused a setting.
    #[error("zenoh config {0}: {1}")]
    Config(String, String),
}

impl LinkError {
    fn io(path: &Path, e: std::io::Error) -> Self {
        LinkError::File {
            path: path.to_path_buf(),
            why: e.to_string(),
        }
    }
}
