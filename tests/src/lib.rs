//! Helpers for the cross-crate tests: building and finding the stage
//! binaries, a guard that kills spawned processes and waiting for them to
//! exit; in modules, two hosts on this machine, the launcher's report, and
//! the Python the tests run.

pub mod hosts;
pub mod python;
pub mod report;

use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Builds the workspace's binaries (test profile) once per test process
/// and returns their directory.
///
/// It builds what `cargo test --workspace --all-targets` builds, binaries
/// included: the same selection resolves every dependency with the same
/// features, so after the test build this compiles only the binaries
/// themselves. (Building the stage packages alone resolved features
/// differently and compiled the dependencies a second time: 8 minutes of
/// CI.)
pub fn stage_binaries() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| build_binaries("test", &["--workspace", "--all-targets"]))
        .clone()
}

/// Builds the workspace's binaries optimised (for benchmarks) and returns
/// their directory.
pub fn release_stage_binaries() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| build_binaries("release", &["--workspace", "--bins"]))
        .clone()
}

fn build_binaries(profile: &str, selection: &[&str]) -> PathBuf {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let status = Command::new(cargo)
        .args(["build", "--quiet", "--profile", profile])
        .args(selection)
        .status()
        .expect("cargo runs");
    assert!(status.success(), "building the workspace's binaries failed");
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

/// Asks `child` (or the process with that pid) to stop, as systemd or the
/// launcher does: SIGTERM.
pub fn terminate(pid: u32) {
    // SAFETY: kill(2) with a pid and a signal number; no memory is shared.
    #[allow(unsafe_code)]
    unsafe {
        libc::kill(pid as i32, libc::SIGTERM);
    }
}

/// Waits at most `within` for `child` to exit and returns its exit status.
/// Panics, naming `what`, if it has not exited by then.
pub fn wait_exit(child: &mut Child, within: Duration, what: &str) -> ExitStatus {
    wait_exit_showing(child, within, what, String::new)
}

/// [`wait_exit`], with `details()` (say the logs to look at) appended to
/// the message it panics with; `details` is called only then.
pub fn wait_exit_showing(
    child: &mut Child,
    within: Duration,
    what: &str,
    details: impl Fn() -> String,
) -> ExitStatus {
    let started = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        assert!(
            started.elapsed() < within,
            "{what} did not exit in {within:?}{}",
            details()
        );
        std::thread::sleep(Duration::from_millis(20));
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
