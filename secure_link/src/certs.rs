//! The run's certificates: one CA, and for each side a certificate it signs
//! whose common name is the side's name, with the side's host names and
//! addresses. Written as `pipeline certs` writes them:
//!
//! ```text
//! DIR/ca.pem            the CA's certificate: both sides trust it
//! DIR/ca.key            the CA's key (0600): neither side needs it
//! DIR/<side>.pem        a side's certificate, signed by the CA
//! DIR/<side>.key        its private key (0600)
//! ```

use std::fs::OpenOptions;
use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use rcgen::{
    BasicConstraints, CertificateParams, DnType, ExtendedKeyUsagePurpose, IsCa, Issuer, KeyPair,
    KeyUsagePurpose,
};
use time::{Duration, OffsetDateTime};

use crate::LinkError;

/// The CA's certificate in a certificates directory.
pub const CA_CERT: &str = "ca.pem";
/// The CA's private key in a certificates directory.
pub const CA_KEY: &str = "ca.key";

/// One side to make a certificate for.
#[derive(Debug, Clone)]
pub struct SideRequest {
    /// The side's name: its files' names and its certificate's common name,
    /// which the other side's access control knows it by.
    pub name: String,
    /// Host names and IP addresses the side is reached at (the certificate's
    /// subject alternative names; a side that connects is not checked
    /// against them, one that listens is).
    pub hosts: Vec<String>,
}

/// What `write` wrote.
#[derive(Debug, Clone)]
pub struct Written {
    /// The CA's certificate.
    pub ca: PathBuf,
    /// Each side's certificate and key, in the request's order.
    pub sides: Vec<(PathBuf, PathBuf)>,
}

/// The certificate and key files of side `name` in `dir`.
pub fn side_files(dir: &Path, name: &str) -> (PathBuf, PathBuf) {
    (
        dir.join(format!("{name}.pem")),
        dir.join(format!("{name}.key")),
    )
}

/// Makes a new CA and a certificate for each of `sides`, valid for `days`
/// from a day ago (a little slack for clocks behind), and writes them into
/// `dir` (made if missing). Refuses to replace an existing CA unless
/// `force`: the certificates already handed out would stop working.
pub fn write(
    dir: &Path,
    sides: &[SideRequest],
    days: u32,
    force: bool,
) -> Result<Written, LinkError> {
    let (ca_cert, ca_key) = (dir.join(CA_CERT), dir.join(CA_KEY));
    if !force && let Some(existing) = [&ca_cert, &ca_key].into_iter().find(|p| p.exists()) {
        return Err(LinkError::CaExists(existing.clone()));
    }
    if days == 0 {
        return Err(LinkError::Certificate("--days must be at least 1".into()));
    }
    let valid_from = OffsetDateTime::now_utc() - Duration::days(1);
    let valid_until = OffsetDateTime::now_utc() + Duration::days(i64::from(days));
    let rcgen_error = |what: &str, e: rcgen::Error| LinkError::Certificate(format!("{what}: {e}"));

    let mut ca = CertificateParams::new(Vec::<String>::new())
        .map_err(|e| rcgen_error("the CA's parameters", e))?;
    ca.distinguished_name
        .push(DnType::CommonName, "mirror perspective run CA");
    ca.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    ca.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    ca.not_before = valid_from;
    ca.not_after = valid_until;
    let ca_key_pair = KeyPair::generate().map_err(|e| rcgen_error("the CA's key", e))?;
    let ca_pem = ca
        .self_signed(&ca_key_pair)
        .map_err(|e| rcgen_error("the CA's certificate", e))?
        .pem();
    let ca_key_pem = ca_key_pair.serialize_pem();
    let issuer = Issuer::new(ca, ca_key_pair);

    let mut made = Vec::new();
    for side in sides {
        check_name(&side.name)?;
        let mut params = CertificateParams::new(side.hosts.clone())
            .map_err(|e| rcgen_error(&format!("{}'s hosts {:?}", side.name, side.hosts), e))?;
        params
            .distinguished_name
            .push(DnType::CommonName, side.name.as_str());
        params.use_authority_key_identifier_extension = true;
        params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
        // Either side may listen or connect.
        params.extended_key_usages = vec![
            ExtendedKeyUsagePurpose::ServerAuth,
            ExtendedKeyUsagePurpose::ClientAuth,
        ];
        params.not_before = valid_from;
        params.not_after = valid_until;
        let key = KeyPair::generate().map_err(|e| rcgen_error(&side.name, e))?;
        let cert = params
            .signed_by(&key, &issuer)
            .map_err(|e| rcgen_error(&format!("{}'s certificate", side.name), e))?;
        made.push((side, cert.pem(), key.serialize_pem()));
    }

    // Everything is made before anything is written: a failure leaves the
    // directory as it was.
    std::fs::create_dir_all(dir).map_err(|e| LinkError::io(dir, e))?;
    write_file(&ca_key, &ca_key_pem, 0o600)?;
    write_file(&ca_cert, &ca_pem, 0o644)?;
    let mut written = Written {
        ca: ca_cert,
        sides: Vec::new(),
    };
    for (side, cert, key) in made {
        let (cert_path, key_path) = side_files(dir, &side.name);
        write_file(&key_path, &key, 0o600)?;
        write_file(&cert_path, &cert, 0o644)?;
        written.sides.push((cert_path, key_path));
    }
    Ok(written)
}

/// A side's name becomes a file name and a common name: plain words only.
fn check_name(name: &str) -> Result<(), LinkError> {
    let plain = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
    if plain && name != "ca" {
        Ok(())
    } else {
        Err(LinkError::Certificate(format!(
            "a side's name must be letters, digits, '-' or '_' (and not \"ca\"), not {name:?}"
        )))
    }
}

/// Writes `text` to `path` with permissions `mode`, replacing what is there
/// (a key's permissions are set when it is created, never loosened after).
fn write_file(path: &Path, text: &str, mode: u32) -> Result<(), LinkError> {
    // Replaced, not truncated: an existing file keeps its own permissions.
    if path.exists() {
        std::fs::remove_file(path).map_err(|e| LinkError::io(path, e))?;
    }
    let mut file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(mode)
        .open(path)
        .map_err(|e| LinkError::io(path, e))?;
    file.write_all(text.as_bytes())
        .and_then(|()| file.sync_all())
        .map_err(|e| LinkError::io(path, e))
}

#[cfg(test)]
mod tests {
    use std::os::unix::fs::PermissionsExt;
    use std::process::Command;

    use super::*;

    fn sides() -> Vec<SideRequest> {
        vec![
            SideRequest {
                name: "robot".into(),
                hosts: vec!["robot.local".into(), "10.0.0.1".into()],
            },
            SideRequest {
                name: "workstation".into(),
                hosts: vec!["localhost".into()],
            },
        ]
    }

    fn openssl(args: &[&str]) -> String {
        let out = Command::new("openssl")
            .args(args)
            .output()
            .expect("openssl");
        assert!(
            out.status.success(),
            "openssl {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    /// OpenSSL, an independent X.509 implementation, verifies each side's
    /// certificate against the CA, for both TLS roles, and reads the names.
    #[test]
    fn openssl_verifies_the_sides_against_the_ca_and_keys_are_private() {
        let dir = tempfile::tempdir().unwrap();
        let written = write(dir.path(), &sides(), 30, false).unwrap();
        let ca = written.ca.to_str().unwrap();
        for (cert, key) in &written.sides {
            let cert = cert.to_str().unwrap();
            for purpose in ["sslserver", "sslclient"] {
                let out = openssl(&["verify", "-purpose", purpose, "-CAfile", ca, cert]);
                assert!(out.contains(": OK"), "{out}");
            }
            let mode = std::fs::metadata(key).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode, 0o600, "{}", key.display());
            // The key is the certificate's.
            let from_key = openssl(&["pkey", "-in", key.to_str().unwrap(), "-pubout"]);
            let from_cert = openssl(&["x509", "-in", cert, "-noout", "-pubkey"]);
            assert_eq!(from_key, from_cert);
        }
        let robot = openssl(&[
            "x509",
            "-in",
            written.sides[0].0.to_str().unwrap(),
            "-noout",
            "-subject",
            "-ext",
            "subjectAltName",
        ]);
        assert!(robot.contains("CN = robot"), "{robot}");
        assert!(
            robot.contains("DNS:robot.local") && robot.contains("IP Address:10.0.0.1"),
            "{robot}"
        );
        let mode = std::fs::metadata(dir.path().join(CA_KEY))
            .unwrap()
            .permissions()
            .mode();
        assert_eq!(mode & 0o777, 0o600);
    }

    /// A certificate of another CA does not verify against this one.
    #[test]
    fn another_run_s_certificate_does_not_verify() {
        let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        write(a.path(), &sides(), 30, false).unwrap();
        let other = write(b.path(), &sides(), 30, false).unwrap();
        let out = Command::new("openssl")
            .args(["verify", "-CAfile"])
            .arg(a.path().join(CA_CERT))
            .arg(&other.sides[0].0)
            .output()
            .unwrap();
        assert!(!out.status.success());
    }

    #[test]
    fn an_existing_ca_is_kept_unless_forced() {
        let dir = tempfile::tempdir().unwrap();
        let first = write(dir.path(), &sides(), 30, false).unwrap();
        let before = std::fs::read_to_string(&first.ca).unwrap();
        let err = write(dir.path(), &sides(), 30, false).unwrap_err();
        assert!(err.to_string().contains("ca.pem"), "{err}");
        assert!(err.to_string().contains("--force"), "{err}");
        assert_eq!(std::fs::read_to_string(&first.ca).unwrap(), before);
        write(dir.path(), &sides(), 30, true).unwrap();
        assert_ne!(std::fs::read_to_string(&first.ca).unwrap(), before);
    }

    #[test]
    fn bad_requests_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let mut bad = sides();
        bad[1].name = "../x".into();
        let err = write(dir.path(), &bad, 30, false).unwrap_err();
        assert!(err.to_string().contains("\"../x\""), "{err}");
        assert!(!dir.path().join(CA_CERT).exists(), "nothing written");
        let err = write(dir.path(), &sides(), 0, false).unwrap_err();
        assert!(err.to_string().contains("--days"), "{err}");
    }
}
