//! Which zenoh endpoints a link may use: `tls/` with certificates; plain
//! `tcp/` on loopback (a test on one host); plain `tcp/` to or from
//! another host only when the user says `--insecure`.

use std::net::IpAddr;

use crate::LinkError;

/// What one endpoint exposes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Exposure {
    /// Mutual TLS: only holders of a certificate of the run's CA.
    Tls,
    /// Plain TCP on loopback: only this host's processes.
    Loopback,
    /// Plain TCP on a network: anyone on it.
    Open,
}

/// Where an endpoint such as `tcp/10.0.0.1:7447#iface=eth0` goes: its
/// protocol and host.
fn split(endpoint: &str) -> Result<(&str, &str), LinkError> {
    let address = endpoint.split(['?', '#']).next().unwrap_or(endpoint);
    let (protocol, rest) = address
        .split_once('/')
        .ok_or_else(|| LinkError::Endpoint(endpoint.into(), "no protocol/ before it".into()))?;
    let host = match rest.strip_prefix('[') {
        Some(v6) => v6.split(']').next().unwrap_or(v6),
        None => rest.rsplit_once(':').map_or(rest, |(host, _port)| host),
    };
    Ok((protocol, host))
}

/// Whether `host` is this host only: a loopback address or `localhost`.
fn is_loopback(host: &str) -> bool {
    host.eq_ignore_ascii_case("localhost")
        || host.parse::<IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

/// What `endpoint` exposes; an error for a protocol the link does not
/// speak (this build has TCP and TLS).
pub fn exposure(endpoint: &str) -> Result<Exposure, LinkError> {
    let (protocol, host) = split(endpoint)?;
    match protocol {
        "tls" => Ok(Exposure::Tls),
        "tcp" if is_loopback(host) => Ok(Exposure::Loopback),
        "tcp" => Ok(Exposure::Open),
        other => Err(LinkError::Endpoint(
            endpoint.into(),
            format!("{other}/ is not a protocol this build speaks: use tls/ (or tcp/ on loopback)"),
        )),
    }
}

/// Checks `endpoints` against what the user gave: a `tls/` endpoint needs
/// `certificates`; certificates need a `tls/` endpoint; a plain `tcp/`
/// endpoint off loopback needs `insecure`, and then is logged as a
/// warning naming what it exposes (`what`, e.g. "the run's frames, joint
/// states and calibration").
pub fn check(
    endpoints: &[String],
    certificates: bool,
    insecure: bool,
    what: &str,
) -> Result<(), LinkError> {
    let mut tls = false;
    for endpoint in endpoints {
        match exposure(endpoint)? {
            Exposure::Tls if !certificates => {
                return Err(LinkError::Endpoint(
                    endpoint.clone(),
                    "tls/ needs the run's certificates: --certs DIR (`pipeline certs --out DIR` makes them)".into(),
                ));
            }
            Exposure::Tls => tls = true,
            Exposure::Loopback => {}
            Exposure::Open if !insecure => {
                return Err(LinkError::Endpoint(
                    endpoint.clone(),
                    format!(
                        "plain TCP to or from another host lets anyone on the network read {what} and send forged data; \
                         use tls/ with --certs DIR (`pipeline certs --out DIR` makes them), or --insecure to accept that"
                    ),
                ));
            }
            Exposure::Open => tracing::warn!(
                "--insecure: {endpoint} is plain TCP; anyone on that network can read {what} and send forged data"
            ),
        }
    }
    if certificates && !tls {
        return Err(LinkError::Endpoint(
            endpoints.join(", "),
            "certificates were given but no endpoint is tls/: they would not be used".into(),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_are_classified_by_protocol_and_host() {
        for (endpoint, expected) in [
            ("tls/robot.local:7447", Exposure::Tls),
            ("tls/10.0.0.1:7447", Exposure::Tls),
            ("tcp/127.0.0.1:7447", Exposure::Loopback),
            ("tcp/127.3.2.1:7447", Exposure::Loopback),
            ("tcp/localhost:7447", Exposure::Loopback),
            ("tcp/[::1]:7447", Exposure::Loopback),
            ("tcp/0.0.0.0:7447", Exposure::Open),
            ("tcp/[::]:7447", Exposure::Open),
            ("tcp/10.0.0.1:7447#iface=eth0", Exposure::Open),
            ("tcp/robot.local:7447", Exposure::Open),
        ] {
            assert_eq!(exposure(endpoint).unwrap(), expected, "{endpoint}");
        }
        let err = exposure("udp/10.0.0.1:7447").unwrap_err().to_string();
        assert!(
            err.contains("udp/10.0.0.1:7447") && err.contains("udp/"),
            "{err}"
        );
        assert!(exposure("10.0.0.1:7447").is_err());
    }

    #[test]
    fn plain_tcp_across_hosts_needs_insecure_and_tls_needs_certificates() {
        let open = ["tcp/10.0.0.1:7447".to_string()];
        let err = check(&open, false, false, "frames")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("tcp/10.0.0.1:7447") && err.contains("--insecure"),
            "{err}"
        );
        check(&open, false, true, "frames").unwrap();
        check(&["tcp/127.0.0.1:7447".to_string()], false, false, "frames").unwrap();
        let tls = ["tls/10.0.0.1:7447".to_string()];
        let err = check(&tls, false, false, "frames").unwrap_err().to_string();
        assert!(err.contains("--certs"), "{err}");
        check(&tls, true, false, "frames").unwrap();
        let err = check(&["tcp/127.0.0.1:7447".to_string()], true, false, "frames")
            .unwrap_err()
            .to_string();
        assert!(err.contains("no endpoint is tls/"), "{err}");
    }
}
