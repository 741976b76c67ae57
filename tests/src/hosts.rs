//! Two hosts on this machine: two network namespaces joined by a veth pair,
//! and commands run on either, optionally with shared memory and an
//! iceoryx2 root of their own and a clock of their own. Needs root.

use std::ffi::OsStr;
use std::process::Command;
use std::sync::atomic::{AtomicU32, Ordering};

/// Whether the root-only tests are to be skipped
/// (`MIRROR_SKIP_ROOT_TESTS=1`); says so if they are.
pub fn skip_root_tests() -> bool {
    let skip = std::env::var_os("MIRROR_SKIP_ROOT_TESTS").is_some_and(|v| v == "1");
    if skip {
        eprintln!("MIRROR_SKIP_ROOT_TESTS=1: skipping a test that needs root");
    }
    skip
}

/// Two network namespaces joined by a veth pair: two hosts' networks on
/// this machine. Removed (with the pair) when dropped.
pub struct TwoHosts {
    /// The namespaces' names.
    pub names: [String; 2],
    /// The veth ends, one in each namespace.
    pub veth: [String; 2],
    /// Each host's IPv4 address on the link.
    pub addresses: [String; 2],
}

impl TwoHosts {
    /// Makes the namespaces and the link, up.
    pub fn new() -> Self {
        static MADE: AtomicU32 = AtomicU32::new(0);
        let n = MADE.fetch_add(1, Ordering::Relaxed);
        let id = format!("{}x{n}", std::process::id());
        let names = [format!("mra{id}"), format!("mrb{id}")];
        let veth = [format!("mva{id}"), format!("mvb{id}")];
        let net = format!("10.{}.{}", 200 + n % 50, std::process::id() % 250);
        let addresses = [format!("{net}.1"), format!("{net}.2")];
        let hosts = Self {
            names,
            veth,
            addresses,
        };
        for ns in &hosts.names {
            ip(&["netns", "add", ns]);
            ip(&["-n", ns, "link", "set", "lo", "up"]);
        }
        ip(&[
            "link",
            "add",
            &hosts.veth[0],
            "type",
            "veth",
            "peer",
            "name",
            &hosts.veth[1],
        ]);
        for k in 0..2 {
            let (ns, dev) = (&hosts.names[k], &hosts.veth[k]);
            ip(&["link", "set", dev, "netns", ns]);
            let address = format!("{}/24", hosts.addresses[k]);
            ip(&["-n", ns, "addr", "add", &address, "dev", dev]);
            ip(&["-n", ns, "link", "set", dev, "up"]);
        }
        hosts
    }

    /// Cuts (`false`) or restores host 0's side of the link.
    pub fn link(&self, up: bool) {
        let state = if up { "up" } else { "down" };
        ip(&["-n", &self.names[0], "link", "set", &self.veth[0], state]);
    }

    /// `program` on host `k` (its network only).
    pub fn command(&self, k: usize, program: impl AsRef<OsStr>) -> Command {
        let mut command = Command::new("ip");
        command.args(["netns", "exec", &self.names[k]]).arg(program);
        command
    }

    /// `program` on host `k` as on a machine of its own: its network, an
    /// empty tmpfs on `/dev/shm` and on iceoryx2's root `/tmp/iceoryx2` in
    /// a mount namespace of its own (so no shared memory or service is
    /// shared with this host or the other), and a CLOCK_MONOTONIC `ahead_s`
    /// ahead of this one's. Arguments added to the command go to `program`.
    pub fn machine(&self, k: usize, ahead_s: i64, program: impl AsRef<OsStr>) -> Command {
        // `ip netns exec` runs its command in a new mount namespace whose
        // mounts do not propagate back; the mounts are made there.
        let script = "mount -t tmpfs tmpfs /dev/shm && mkdir -p /tmp/iceoryx2 && \
                      mount -t tmpfs tmpfs /tmp/iceoryx2 && ahead=$1 && shift && \
                      exec unshare --time --fork --kill-child=SIGTERM --monotonic \"$ahead\" \"$@\"";
        let mut command = self.command(k, "sh");
        command
            .args(["-c", script, "sh", &ahead_s.to_string()])
            .arg(program);
        command
    }
}

impl Default for TwoHosts {
    fn default() -> Self {
        Self::new()
    }
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        for ns in &self.names {
            let _ = Command::new("ip").args(["netns", "del", ns]).status();
        }
    }
}

/// Runs `ip` with `args`; panics with its error (and the reason it may
/// have) if it fails.
pub fn ip(args: &[&str]) {
    let out = Command::new("ip").args(args).output().expect("ip runs");
    assert!(
        out.status.success(),
        "ip {}: {} (the tests of two hosts need root; MIRROR_SKIP_ROOT_TESTS=1 skips them)",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr).trim()
    );
}
