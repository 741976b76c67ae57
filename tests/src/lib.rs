//! Helpers for the cross-crate tests: building and finding the stage
//! binaries, and a guard that kills spawned processes.

use std::path::PathBuf;
use std::process::{Child, Command};
use std::sync::OnceLock;

/// Builds the stage binaries (test profile) once per test run and returns
/// their directory.
pub fn stage_binaries() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let status = Command::new(cargo)
            // The test profile reuses what `cargo test` just compiled.
            .args(["build", "--quiet", "--profile", "test", "--bins"])
            .args([
                "-p",
                "camera_proc",
                "-p",
                "tracker_proc",
                "-p",
                "kinematics_proc",
                "-p",
                "mirror_proc",
                "-p",
                "pipeline",
                "-p",
                "recorder",
            ])
            .status()
            .expect("cargo runs");
        assert!(status.success(), "building the stage binaries failed");
        // target/debug/deps/<test> -> target/debug
        let exe = std::env::current_exe().expect("test executable");
        exe.parent()
            .and_then(|p| p.parent())
            .expect("target dir")
            .to_path_buf()
    })
    .clone()
}

/// Kills its child when dropped, so a failing test leaves no process behind.
pub struct KillOnDrop(pub Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A service prefix unique to this test process and `name`.
pub fn unique_prefix(name: &str) -> String {
    format!("test{}_{name}", std::process::id())
}
