//! A real arm's driver: the user's command, given the driver contract's
//! arguments (`--prefix`, `--rig`) and the contract's ports
//! ([`crate::sim_arm::DRIVER_PORTS`]).

use std::path::{Path, PathBuf};

use runtime::Ports;
use serde::Serialize;

use crate::{FixedPorts, Home, RestartPolicy, Side, Stage};

/// The arguments every arm driver is given.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
pub struct Args {
    /// The user's command, split into words: the program and its own
    /// arguments (not part of the contract).
    #[arg(skip)]
    #[serde(skip)]
    pub command: Vec<String>,
    /// Service prefix of the pipeline.
    #[arg(long)]
    pub prefix: String,
    /// Rig file (TOML) with the arm.
    #[arg(long)]
    pub rig: PathBuf,
}

/// A user's arm driver's declaration.
pub struct ArmDriver;

impl FixedPorts for ArmDriver {
    const PORTS: Ports<'static> = crate::sim_arm::DRIVER_PORTS;
}

impl Stage for ArmDriver {
    type Args = Args;
    /// Its name in logs and reports (it is the user's program).
    const BINARY: &'static str = "arm_driver";
    const HOME: Home = Home::On(Side::Robot);
    const SAMPLE_PATH_DEPTH: Option<u8> = Some(5);
    const SOURCE: bool = true;
    /// It stops when the plan is finished, or is stopped with the run.
    const RESTART: RestartPolicy = RestartPolicy::Finishes;

    fn ports(_: &Args) -> Ports<'_> {
        Self::PORTS
    }

    fn prefix(args: &Args) -> &str {
        &args.prefix
    }

    fn example() -> Args {
        Args {
            command: vec!["py".into(), "my driver.py".into(), "-v".into()],
            prefix: "p".into(),
            rig: "r.toml".into(),
        }
    }

    /// The user's command is the program and its own words, not an
    /// argument: everything else comes back.
    fn parsed_again(args: &Args, parsed: &Args) -> bool {
        parsed.command.is_empty()
            && Args {
                command: args.command.clone(),
                ..parsed.clone()
            } == *args
    }

    /// The first word of the user's command (found on `PATH` if it has no `/`).
    fn program(args: &Args, _bin_dir: &Path) -> PathBuf {
        PathBuf::from(args.command.first().map_or("", String::as_str))
    }

    /// The user's own words after the program.
    fn leading_words(args: &Args) -> Vec<String> {
        args.command.iter().skip(1).cloned().collect()
    }
}
