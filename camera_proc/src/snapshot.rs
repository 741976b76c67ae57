//! One rendered stereo pair to PNG files, for looking at the simulated scene.

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Vector};

use geometry::sim::{Facing, SimWorld};
use renderer::Renderer;
use renderer::look::{Look, LookName};

use crate::CameraError;

/// Renders one stereo pair of the simulated scene in `look` with the arm at `q`
/// (encoder readings, rad) to `OUT_left.png` and `OUT_right.png`, and
/// prints which markers each image shows. Joint angles that do not fit
/// the simulated arm are a [`CameraError::JointCount`].
pub fn snapshot(
    mirror: usize,
    q: &[f64],
    facing: Facing,
    look: LookName,
    out: &Path,
) -> Result<(), CameraError> {
    let world = SimWorld::nico(mirror)?;
    let intr = world.rig.cameras[0].intrinsics;
    let dof = world.rig.arm.as_ref().map_or(0, |a| a.dof());
    if q.len() != dof {
        return Err(CameraError::JointCount {
            given: q.len(),
            dof,
        });
    }
    let mut renderer = Renderer::with_look(world, Look::named(look))?;
    let n = (intr.width * intr.height) as usize;
    let (mut left, mut right) = (vec![0u8; n], vec![0u8; n]);
    let truth = renderer.render(q, facing, 0, &mut left, &mut right)?;
    for (side, data, markers) in [
        ("left", &mut left, &truth.markers[0]),
        ("right", &mut right, &truth.markers[1]),
    ] {
        let path = PathBuf::from(format!("{}_{side}.png", out.display()));
        let mat = Mat::new_rows_cols_with_data_mut(
            intr.height as i32,
            intr.width as i32,
            data.as_mut_slice(),
        )?;
        opencv::imgcodecs::imwrite(&path, &mat, &Vector::new()).map_err(|source| {
            CameraError::Write {
                path: path.clone(),
                source,
            }
        })?;
        let drawn: Vec<String> = markers
            .iter()
            .map(|m| format!("id {}{}", m.0, if m.1 { " (mirrored)" } else { "" }))
            .collect();
        println!(
            "{}: {}",
            path.display(),
            if drawn.is_empty() {
                "no markers".into()
            } else {
                drawn.join(", ")
            }
        );
    }
    Ok(())
}
