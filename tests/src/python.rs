//! The Python the tests run: the virtual environment the scripts set up in
//! `target/pyenv`.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The path of the virtual environment's Python,
/// `target/pyenv/bin/python`, whether it exists or not.
pub fn venv_python_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/pyenv/bin/python")
}

/// The Python with the PyPI `mcap` reader and the Foxglove schemas that
/// `scripts/test.sh` installs: `MIRROR_TEST_PYTHON` if set, else the
/// virtual environment's. Panics if the latter is missing.
pub fn python_with_mcap_reader() -> PathBuf {
    if let Ok(p) = std::env::var("MIRROR_TEST_PYTHON") {
        return p.into();
    }
    let venv = venv_python_path();
    assert!(
        venv.exists(),
        "{} is missing: run scripts/test.sh once (it installs the PyPI `mcap` reader and the \
         Foxglove schemas there), or set MIRROR_TEST_PYTHON",
        venv.display()
    );
    venv
}

/// The virtual environment's Python, with the driver SDK installed
/// (`bash scripts/setup.sh`). Panics if it cannot import `mirror_driver`.
pub fn python_with_driver_sdk() -> PathBuf {
    venv_python_importing("mirror_driver", "run `bash scripts/setup.sh`")
}

/// The virtual environment's Python with PyPI `eclipse-zenoh` and
/// `rosbags` (`scripts/test.sh` installs them): an independent ROS 2 wire.
/// Panics if it cannot import them.
pub fn python_with_ros2_wire() -> PathBuf {
    venv_python_importing(
        "zenoh, rosbags",
        "run `bash scripts/test.sh` once (it installs them)",
    )
}

/// The virtual environment's Python with PyPI `eclipse-zenoh`
/// (`scripts/test.sh` installs it): a zenoh peer that is none of ours.
pub fn python_with_zenoh() -> PathBuf {
    venv_python_importing("zenoh", "run `bash scripts/test.sh` once (it installs it)")
}

/// The virtual environment's Python, if it can `import modules`; else
/// panics, saying what to run (`fix`).
fn venv_python_importing(modules: &str, fix: &str) -> PathBuf {
    let python = venv_python_path();
    let ok = Command::new(&python)
        .args(["-c", &format!("import {modules}")])
        .status()
        .is_ok_and(|s| s.success());
    assert!(ok, "{} cannot import {modules}: {fix}", python.display());
    python
}
