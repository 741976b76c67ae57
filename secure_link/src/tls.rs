//! A side's identity on a link (the run's CA, its certificate and key) as
//! zenoh's mutual TLS settings, and the access control that says what the
//! side at the other end may do.
//!
//! Zenoh's settings are those of `transport/link/tls` in zenoh 1.10
//! (zenoh-config `TLSConf`; zenoh-link-tls `utils.rs`): with `enable_mtls`
//! a listener requires a client certificate signed by `root_ca_certificate`
//! (TLS 1.3), and a connector sends its own only when it is set too. Each
//! side's access control then knows the other by its certificate's common
//! name (zenoh-link-tls `unicast.rs`: the client's on the listener, the
//! server's on the connector), and filters every message both ways on the
//! link (zenoh `net/routing/interceptor/access_control.rs`, peer mode
//! included).

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

use crate::LinkError;
use crate::certs::{CA_CERT, side_files};

/// The files a side holds: the CA it trusts, its certificate and its key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// The run's CA certificate.
    pub ca: PathBuf,
    /// This side's certificate, signed by the CA.
    pub cert: PathBuf,
    /// This side's private key.
    pub key: PathBuf,
}

impl Identity {
    /// Side `name`'s identity in a directory as `pipeline certs` writes it.
    pub fn of_side(dir: &Path, name: &str) -> Self {
        let (cert, key) = side_files(dir, name);
        Self {
            ca: dir.join(CA_CERT),
            cert,
            key,
        }
    }

    /// Every file is there and readable, and the key is not readable by
    /// anyone but its owner (as ssh insists for its keys).
    pub fn check(&self) -> Result<(), LinkError> {
        for path in [&self.ca, &self.cert, &self.key] {
            std::fs::File::open(path).map_err(|e| LinkError::File {
                path: path.clone(),
                why: format!("{e} (`pipeline certs --out DIR` makes the run's certificates)"),
            })?;
        }
        let mode = std::fs::metadata(&self.key)
            .map_err(|e| LinkError::io(&self.key, e))?
            .permissions()
            .mode();
        if mode & 0o077 != 0 {
            return Err(LinkError::File {
                path: self.key.clone(),
                why: format!(
                    "a private key readable by others (mode {:04o}); `chmod 600 {}`",
                    mode & 0o7777,
                    self.key.display()
                ),
            });
        }
        Ok(())
    }

    /// Sets zenoh's mutual TLS to this identity, for listening and for
    /// connecting: the other end must show a certificate of the same CA,
    /// and a listener's must name the host it was reached at.
    pub fn configure(&self, config: &mut zenoh::Config) -> Result<(), LinkError> {
        self.check()?;
        let path = |p: &Path| serde_json::to_string(&p.to_string_lossy()).expect("a string");
        let settings = [
            ("root_ca_certificate", path(&self.ca)),
            ("listen_certificate", path(&self.cert)),
            ("listen_private_key", path(&self.key)),
            ("connect_certificate", path(&self.cert)),
            ("connect_private_key", path(&self.key)),
            ("enable_mtls", "true".into()),
            ("verify_name_on_connect", "true".into()),
            // A link whose certificate expires ends with it.
            ("close_link_on_expiration", "true".into()),
        ];
        for (key, value) in settings {
            set(config, &format!("transport/link/tls/{key}"), &value)?;
        }
        Ok(())
    }
}

/// Sets zenoh's TLS to trust only `ca` for a server's certificate, with no
/// certificate of our own (a router that does not ask for one).
pub fn trust(config: &mut zenoh::Config, ca: &Path) -> Result<(), LinkError> {
    std::fs::File::open(ca).map_err(|e| LinkError::io(ca, e))?;
    let ca = serde_json::to_string(&ca.to_string_lossy()).expect("a string");
    set(config, "transport/link/tls/root_ca_certificate", &ca)?;
    set(config, "transport/link/tls/verify_name_on_connect", "true")
}

/// Which way a message crosses the link, seen from this side.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// From the other side to this one.
    Ingress,
    /// From this side to the other.
    Egress,
}

/// One thing the other side may do: `messages` (zenoh's names: `put`,
/// `declare_subscriber`, `query`, `declare_queryable`, `reply`, ...) on
/// keys included in `keys`, in `flow`.
#[derive(Debug, Clone)]
pub struct Allow {
    /// A short name for the rule.
    pub id: &'static str,
    /// Zenoh message kinds.
    pub messages: &'static [&'static str],
    /// Which way.
    pub flow: Flow,
    /// Key expressions a message's key must be included in.
    pub keys: Vec<String>,
}

/// Sets zenoh's access control: the side whose certificate's common name is
/// `peer` may do what `allows` says over TLS, and nothing else from anyone
/// (zenoh drops what is denied, both ways). Rules without keys are left
/// out (zenoh refuses an empty list).
pub fn restrict_to(
    config: &mut zenoh::Config,
    peer: &str,
    allows: &[Allow],
) -> Result<(), LinkError> {
    let rules: Vec<serde_json::Value> = allows
        .iter()
        .filter(|a| !a.keys.is_empty())
        .map(|a| {
            serde_json::json!({
                "id": a.id,
                "messages": a.messages,
                "flows": [match a.flow { Flow::Ingress => "ingress", Flow::Egress => "egress" }],
                "permission": "allow",
                "key_exprs": a.keys,
            })
        })
        .collect();
    let ids: Vec<&serde_json::Value> = rules.iter().map(|r| &r["id"]).collect();
    let acl = serde_json::json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        // Only a TLS link carries a common name; the protocol is named too,
        // so that no other link could ever match.
        "subjects": [{ "id": "peer", "cert_common_names": [peer], "link_protocols": ["tls"] }],
        "policies": [{ "id": "peer", "rules": ids, "subjects": ["peer"] }],
    });
    set(config, "access_control", &acl.to_string())
}

fn set(config: &mut zenoh::Config, key: &str, value: &str) -> Result<(), LinkError> {
    config
        .insert_json5(key, value)
        .map_err(|e| LinkError::Config(format!("{key} = {value}"), e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::certs::{self, SideRequest};

    fn identity(dir: &Path) -> Identity {
        let side = SideRequest {
            name: "robot".into(),
            hosts: vec!["localhost".into()],
        };
        certs::write(dir, &[side], 1, false).unwrap();
        Identity::of_side(dir, "robot")
    }

    #[test]
    fn a_key_open_to_others_or_a_missing_file_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let id = identity(dir.path());
        id.check().unwrap();
        std::fs::set_permissions(&id.key, std::fs::Permissions::from_mode(0o644)).unwrap();
        let err = id.check().unwrap_err().to_string();
        assert!(err.contains("robot.key") && err.contains("0644"), "{err}");
        let err = Identity::of_side(dir.path(), "workstation")
            .check()
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("workstation.pem") && err.contains("pipeline certs"),
            "{err}"
        );
    }

    /// Zenoh takes the settings as given (its own schema checks them).
    #[test]
    fn zenoh_takes_the_tls_and_access_control_settings() {
        let dir = tempfile::tempdir().unwrap();
        let id = identity(dir.path());
        let mut config = zenoh::Config::default();
        id.configure(&mut config).unwrap();
        restrict_to(
            &mut config,
            "workstation",
            &[
                Allow {
                    id: "put_in",
                    messages: &["put"],
                    flow: Flow::Ingress,
                    keys: vec!["ns/calibration".into()],
                },
                Allow {
                    id: "nothing",
                    messages: &["put"],
                    flow: Flow::Egress,
                    keys: Vec::new(),
                },
            ],
        )
        .unwrap();
        let enabled = config.get_json("access_control/enabled").unwrap();
        assert_eq!(enabled, "true");
        let ca = config
            .get_json("transport/link/tls/root_ca_certificate")
            .unwrap();
        assert!(ca.contains("ca.pem"), "{ca}");
        let rules = config.get_json("access_control/rules").unwrap();
        assert!(
            rules.contains("put_in") && !rules.contains("nothing"),
            "{rules}"
        );
    }
}
