//! `pipeline --replay FILE`: what a recording holds to re-run its stages.
//! The recorder attaches the rig (and the files it refers to), the plan and
//! the run's config, and notes the placement in its `run` metadata.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use recorder::reader::Recording;

/// The files unpacked from a recording.
#[derive(Debug)]
pub struct Unpacked {
    /// The run's config, written into the output directory.
    pub config: PathBuf,
    /// The mirror placement the recording was made at.
    pub mirror: usize,
}

/// Writes the recording's attachments into `out` and finds its config and
/// placement.
pub fn unpack(file: &Path, out: &Path) -> Result<Unpacked> {
    let extras = Recording::open(file)?.extras()?;
    let mirror = extras
        .metadata
        .get("run")
        .and_then(|run| run.get("mirror"))
        .and_then(|m| m.parse::<usize>().ok())
        .with_context(|| {
            format!(
                "{}: no placement in its run metadata (not recorded by the pipeline)",
                file.display()
            )
        })?;
    let mut config = None;
    let mut names = Vec::new();
    for (name, data) in extras.attachments {
        // Only a plain file name: an attachment cannot write elsewhere.
        let Some(base) = Path::new(&name).file_name().filter(|b| *b == name.as_str()) else {
            bail!(
                "{}: attachment `{name}` is not a plain file name",
                file.display()
            );
        };
        let path = out.join(base);
        std::fs::write(&path, &data)
            .with_context(|| format!("{}: cannot write", path.display()))?;
        if name.ends_with(".toml") && name != "rig.toml" {
            config = Some(path);
        }
        names.push(name);
    }
    for needed in ["rig.toml", "plan.csv"] {
        if !names.iter().any(|n| n == needed) {
            bail!(
                "{}: no {needed} attached (a recording made by the pipeline holds the rig, plan and config)",
                file.display()
            );
        }
    }
    let config = config.with_context(|| format!("{}: no run config attached", file.display()))?;
    Ok(Unpacked { config, mirror })
}
