//! Helpers for the cross-crate tests: building and finding the stage
//! binaries, and a guard that kills spawned processes.

pub mod hosts;

use std::path::PathBuf;
use std::process::{Child, Command};
use std::sync::OnceLock;

/// The stage binaries, for `cargo build` or `cargo run`.
pub const STAGE_PACKAGES: [&str; 7] = [
    "bridge",
    "camera_proc",
    "tracker_proc",
    "kinematics_proc",
    "mirror_proc",
    "pipeline",
    "recorder",
];

/// Builds the stage binaries (test profile) once per test run and returns
/// their directory.
pub fn stage_binaries() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    // The test profile reuses what `cargo test` just compiled.
    DIR.get_or_init(|| build_stage_binaries("test")).clone()
}

/// Builds the stage binaries optimised (for benchmarks) and returns their
/// directory.
pub fn release_stage_binaries() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| build_stage_binaries("release")).clone()
}

fn build_stage_binaries(profile: &str) -> PathBuf {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut command = Command::new(cargo);
    command.args(["build", "--quiet", "--profile", profile, "--bins"]);
    for package in STAGE_PACKAGES {
        command.args(["-p", package]);
    }
    let status = command.status().expect("cargo runs");
    assert!(status.success(), "building the stage binaries failed");
    // target/<dir>/deps/<test or bench> -> target/<dir>
    let exe = std::env::current_exe().expect("test executable");
    let built_beside_us = exe
        .parent()
        .and_then(|p| p.parent())
        .expect("target dir")
        .to_path_buf();
    match profile {
        "test" => built_beside_us,
        // A benchmark runs from target/release already; anything else
        // (a benchmark in test mode) finds release beside its own profile.
        _ => built_beside_us.parent().expect("target dir").join(profile),
    }
}

/// Kills its child when dropped, so a failing test leaves no process behind.
pub struct KillOnDrop(pub Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A TCP port on 127.0.0.1 that nothing listens on, for a link under test
/// to listen on. Taken below Linux's ephemeral range (32768 and up): a port
/// the kernel hands out for binding port 0 is also one it hands to outgoing
/// connections, and a zenoh peer of a test running beside this one took
/// such a port between its check and the listen. Each test process starts
/// at its own place and never offers a port twice.
pub fn free_port() -> u16 {
    use std::sync::atomic::{AtomicU16, Ordering};
    const FIRST: u16 = 20_000;
    const SPAN: u16 = 12_000;
    static NEXT: AtomicU16 = AtomicU16::new(0);
    let start = (std::process::id() % u32::from(SPAN)) as u16;
    loop {
        let k = NEXT.fetch_add(1, Ordering::Relaxed);
        assert!(
            k < SPAN,
            "no free TCP port left in {FIRST}..{}",
            FIRST + SPAN
        );
        let port = FIRST + (start + k) % SPAN;
        if std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
}

/// A service prefix unique to this test process and `name`.
pub fn unique_prefix(name: &str) -> String {
    format!("test{}_{name}", std::process::id())
}
