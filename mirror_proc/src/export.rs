//! `mirror_proc export`: a calibration in the forms robot tools read.
//!
//! Writes into the output folder:
//!
//! - `mirror.json`: the mirror plane and mirror cameras (poses, projection
//!   matrices), world frame, mm ([`formats::export::mirror_json`]);
//! - `frame_transforms.json`: the same frames as a Foxglove
//!   `FrameTransforms` snapshot (metres);
//! - for a URDF arm, `<name>.corrected.urdf`: the input URDF with the
//!   estimated joint offsets folded into the joint origins;
//! - for any arm, `rig.corrected.toml`: the rig with the calibrated arm
//!   (its DH table's `theta_offset`s corrected, or pointing at the
//!   corrected URDF; the estimated `world_from_base` and `tool`, if the
//!   calibration has them), which gives at `q` what the calibration gives
//!   at `q + joint_offsets`.

use std::path::{Path, PathBuf};

use formats::FormatError;
use geometry::ArmModel;

/// Why an export failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The rig, the calibration or the URDF could not be read, does not
    /// fit the others, or could not be corrected.
    #[error(transparent)]
    Format(#[from] FormatError),
    /// The output folder or a file in it could not be created or written.
    #[error("{}: {what}", path.display())]
    Io {
        /// The folder or file.
        path: PathBuf,
        /// What was being done: `cannot create`, `cannot write`.
        what: &'static str,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

fn write(path: PathBuf, text: &str, written: &mut Vec<PathBuf>) -> Result<(), ExportError> {
    if let Err(source) = std::fs::write(&path, text) {
        return Err(ExportError::Io {
            path,
            what: "cannot write",
            source,
        });
    }
    written.push(path);
    Ok(())
}

/// Exports the calibration at `cal_path`, made with the rig at `rig_path`,
/// into `out` (created). Returns the files written.
pub fn export(rig_path: &Path, cal_path: &Path, out: &Path) -> Result<Vec<PathBuf>, ExportError> {
    let rig = formats::rig::read(rig_path)?;
    let cal = formats::calibration::read(cal_path)?;
    cal.check_arm(cal_path, &rig)?;
    // The arm's base and tool as calibrated, where the calibration
    // estimated them: the corrected rig carries them.
    let rig = cal.corrected_rig(cal_path, &rig)?;
    std::fs::create_dir_all(out).map_err(|source| ExportError::Io {
        path: out.to_path_buf(),
        what: "cannot create",
        source,
    })?;
    let mut written = Vec::new();
    write(
        out.join("mirror.json"),
        &formats::export::mirror_json(&cal, &rig),
        &mut written,
    )?;
    write(
        out.join("frame_transforms.json"),
        &formats::export::frame_transforms_json(&cal, &rig),
        &mut written,
    )?;
    let Some(arm) = &rig.arm else {
        return Ok(written);
    };
    let offsets = cal
        .joint_offsets
        .clone()
        .unwrap_or_else(|| vec![0.0; arm.dof()]);
    let corrected = match &arm.model {
        ArmModel::Dh(_) => formats::export::corrected_dh_rig(&rig, &offsets)
            .expect("checked: a DH arm with one offset per joint"),
        ArmModel::Chain(chain) => {
            let source = chain
                .source
                .as_ref()
                .expect("a chain arm comes from a URDF");
            let input = Path::new(&source.urdf);
            let text = formats::read_text(input)?;
            let fixed = formats::urdf::corrected(
                input,
                &text,
                &source.base_link,
                &source.tip_link,
                &offsets,
            )?;
            let stem = input
                .file_stem()
                .map_or_else(|| "robot".into(), |s| s.to_string_lossy());
            let name = format!("{stem}.corrected.urdf");
            let path = out.join(&name);
            write(path.clone(), &fixed, &mut written)?;
            let mut new_chain = formats::urdf::read(&path, &source.base_link, &source.tip_link)?;
            // Beside the corrected rig, so the pair moves together.
            if let Some(s) = new_chain.source.as_mut() {
                s.urdf = name;
            }
            let mut rig = rig.clone();
            if let Some(a) = rig.arm.as_mut() {
                a.model = ArmModel::Chain(new_chain);
            }
            rig
        }
    };
    write(
        out.join("rig.corrected.toml"),
        &formats::rig::to_toml(&corrected),
        &mut written,
    )?;
    Ok(written)
}
