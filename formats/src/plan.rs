//! The pose plan (CSV with a header row): the poses the arm is driven
//! through, in order.
//!
//! | column | meaning |
//! |---|---|
//! | `pose` | pose id |
//! | `role` | `train`, `test` or `direct` |
//! | `q0`..`qN-1` | joint angles as the encoders will read them, rad |

use std::path::Path;

use geometry::Role;

use crate::{FormatError, write_text};

/// One pose of the plan.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedPose {
    /// Pose id.
    pub pose: u64,
    /// What the pose is for.
    pub role: Role,
    /// Joint angles (as the encoders will read them), rad.
    pub q: Vec<f64>,
}

/// Reads a plan for an arm of `dof` joints.
pub fn read(path: impl AsRef<Path>, dof: usize) -> Result<Vec<PlannedPose>, FormatError> {
    let path = path.as_ref();
    let line = |n: u64| Some(format!("line {n}"));
    let file = std::fs::File::open(path)
        .map_err(|e| FormatError::new(path, None, format!("cannot read: {e}")))?;
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_reader(file);
    let header = reader
        .headers()
        .map_err(|e| FormatError::new(path, line(1), format!("bad header: {e}")))?
        .clone();
    let column = |name: &str, why: &str| {
        header
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| FormatError::new(path, line(1), format!("missing column `{name}`{why}")))
    };
    let pose_col = column("pose", "")?;
    let role_col = column("role", "")?;
    let q_cols: Vec<usize> = (0..dof)
        .map(|i| column(&format!("q{i}"), &format!(" (the arm has {dof} joints)")))
        .collect::<Result<_, _>>()?;
    let mut plan = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| {
            let at = e.position().and_then(|p| line(p.line()));
            FormatError::new(path, at, format!("bad row: {e}"))
        })?;
        let at = line(record.position().map_or(0, |p| p.line()));
        let cell = |c: usize| record.get(c).unwrap_or("");
        let pose = cell(pose_col).parse().map_err(|_| {
            FormatError::new(
                path,
                at.clone(),
                format!(
                    "`pose` must be a whole number >= 0, not `{}`",
                    cell(pose_col)
                ),
            )
        })?;
        let role = Role::from_name(cell(role_col)).ok_or_else(|| {
            FormatError::new(
                path,
                at.clone(),
                format!(
                    "`role` must be train, test or direct, not `{}`",
                    cell(role_col)
                ),
            )
        })?;
        let q = q_cols
            .iter()
            .map(|&c| match cell(c).parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(FormatError::new(
                    path,
                    at.clone(),
                    format!("`{}` is not a finite joint angle", cell(c)),
                )),
            })
            .collect::<Result<_, _>>()?;
        plan.push(PlannedPose { pose, role, q });
    }
    Ok(plan)
}

/// Writes a plan.
pub fn write(path: impl AsRef<Path>, plan: &[PlannedPose]) -> Result<(), FormatError> {
    let dof = plan.first().map_or(0, |p| p.q.len());
    let mut text = String::from("pose,role");
    for i in 0..dof {
        text += &format!(",q{i}");
    }
    text += "\n";
    for p in plan {
        text += &format!("{},{}", p.pose, p.role.as_str());
        for q in &p.q {
            text += &format!(",{q}");
        }
        text += "\n";
    }
    write_text(path.as_ref(), &text)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan() -> Vec<PlannedPose> {
        vec![
            PlannedPose {
                pose: 7,
                role: Role::Train,
                q: vec![1.0, -1.0],
            },
            PlannedPose {
                pose: 8,
                role: Role::Direct,
                q: vec![2.0, 0.1 + 0.2],
            },
        ]
    }

    #[test]
    fn plans_round_trip_and_bad_rows_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("plan.csv");
        write(&path, &plan()).unwrap();
        assert_eq!(read(&path, 2).unwrap(), plan());
        let e = read(&path, 3).unwrap_err().to_string();
        assert!(
            e.ends_with("plan.csv: line 1: missing column `q2` (the arm has 3 joints)"),
            "{e}"
        );
        std::fs::write(&path, "pose,role,q0\n1,train,NaN\n").unwrap();
        let e = read(&path, 1).unwrap_err().to_string();
        assert!(
            e.ends_with("plan.csv: line 2: `NaN` is not a finite joint angle"),
            "{e}"
        );
        std::fs::write(&path, "pose,role,q0\n1,train,0\n2,calibrate,0\n").unwrap();
        let e = read(&path, 1).unwrap_err().to_string();
        assert!(
            e.ends_with("line 3: `role` must be train, test or direct, not `calibrate`"),
            "{e}"
        );
        std::fs::write(&path, "pose,role,q0\n-1,train,0\n").unwrap();
        let e = read(&path, 1).unwrap_err().to_string();
        assert!(e.contains("line 2: `pose` must be a whole number"), "{e}");
        let e = read(dir.path().join("none.csv"), 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.csv: cannot read"), "{e}");
    }
}
