//! `pipeline certs`: the certificates of a run split across two hosts, and
//! what to run on each side with them.

use std::path::{Path, PathBuf};

use anyhow::Result;
use secure_link::certs::{self, SideRequest};

use crate::split::{DEFAULT_NAMESPACE, Side};

/// Make the certificates for a run split across two hosts: a CA of its own,
/// and a certificate for the robot and one for the workstation, which the
/// bridges show each other (mutual TLS).
#[derive(Debug, clap::Args)]
pub struct CertsArgs {
    /// Directory to write `ca.pem`, `ca.key`, `robot.pem`, `robot.key`,
    /// `workstation.pem` and `workstation.key` into (made if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Host names or addresses the robot is reached at (comma-separated or
    /// repeated), e.g. `robot.local,192.168.1.20`: a side that connects
    /// checks the one it listens at is among them. `localhost` and
    /// `127.0.0.1` are always included.
    #[arg(long, value_delimiter = ',')]
    pub robot_host: Vec<String>,
    /// Host names or addresses the workstation is reached at, as for the
    /// robot (needed when the workstation listens).
    #[arg(long, value_delimiter = ',')]
    pub workstation_host: Vec<String>,
    /// Days the certificates are valid.
    #[arg(long, default_value_t = 3650)]
    pub days: u32,
    /// Replace an existing CA in `--out` (the certificates made with it
    /// stop working).
    #[arg(long)]
    pub force: bool,
}

/// Writes the certificates and prints what to copy where and run.
pub fn run(args: &CertsArgs) -> Result<()> {
    let hosts = |given: &[String]| -> Vec<String> {
        let mut hosts = given.to_vec();
        for local in ["localhost", "127.0.0.1"] {
            if !hosts.iter().any(|h| h == local) {
                hosts.push(local.into());
            }
        }
        hosts
    };
    let sides = [
        SideRequest {
            name: Side::Robot.name().into(),
            hosts: hosts(&args.robot_host),
        },
        SideRequest {
            name: Side::Workstation.name().into(),
            hosts: hosts(&args.workstation_host),
        },
    ];
    let written = certs::write(&args.out, &sides, args.days, args.force)?;
    let dir = &args.out;
    let show = |p: &Path| p.display().to_string();
    println!(
        "wrote the run's CA and certificates into {} (valid {} days; keys 0600):",
        dir.display(),
        args.days
    );
    println!(
        "  {}, {}: the CA; ca.key stays here, neither side needs it",
        show(&written.ca),
        show(&dir.join(certs::CA_KEY))
    );
    for (side, (cert, key)) in sides.iter().zip(&written.sides) {
        println!(
            "  {}, {}: the {} (valid for {})",
            show(cert),
            show(key),
            side.name,
            side.hosts.join(", ")
        );
    }
    let robot_at = args.robot_host.first().map_or("ROBOT", String::as_str);
    println!(
        "\nOn the robot, with ca.pem, robot.pem and robot.key in certs/ (scp -p keeps the key private):\n\
         \x20 pipeline --side robot --listen tls/0.0.0.0:7447 --certs certs\n\
         On the workstation, with ca.pem, workstation.pem and workstation.key in certs/:\n\
         \x20 pipeline --side workstation --connect tls/{robot_at}:7447 --certs certs\n\
         (both with the same --config; a second robot gets its own certificates and --namespace, \
         the default being {DEFAULT_NAMESPACE})"
    );
    if args.robot_host.is_empty() {
        println!(
            "note: no --robot-host: the robot's certificate holds only localhost and 127.0.0.1, \
             so a workstation on another host cannot connect to it"
        );
    }
    Ok(())
}
