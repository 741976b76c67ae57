//! The samples file (CSV with a header row; columns in any order).
//!
//! | column | meaning |
//! |---|---|
//! | `pose` | pose id (optional; defaults to the row number) |
//! | `view` | `mirror` or `direct` (optional; default `mirror`) |
//! | `q0`..`qN-1` | joint angles, rad (needed when `J` comes from the rig's arm) |
//! | `jx`,`jy`,`jz` | the end-effector model's prediction `J`, mm (optional) |
//! | `left_u`,`left_v`,`right_u`,`right_v` | raw (distorted) marker centre, px |

use std::collections::HashMap;
use std::path::Path;

use geometry::{Sample, View};
use nalgebra::{Vector2, Vector3};

use crate::{FormatError, write_text};

const PIXEL_COLUMNS: [&str; 4] = ["left_u", "left_v", "right_u", "right_v"];
const MODEL_COLUMNS: [&str; 3] = ["jx", "jy", "jz"];

/// Reads a samples file. With `arm_dof`, the joint columns must match the arm.
pub fn read(path: impl AsRef<Path>, arm_dof: Option<usize>) -> Result<Vec<Sample>, FormatError> {
    let path = path.as_ref();
    let file = std::fs::File::open(path)
        .map_err(|e| FormatError::new(path, None, format!("cannot read: {e}")))?;
    parse(path, file, arm_dof)
}

/// Parses samples CSV from any reader; `path` is only used in error messages.
pub fn parse(
    path: &Path,
    input: impl std::io::Read,
    arm_dof: Option<usize>,
) -> Result<Vec<Sample>, FormatError> {
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_reader(input);
    let header = reader
        .headers()
        .map_err(|e| FormatError::new(path, Some("line 1".into()), format!("bad header: {e}")))?
        .clone();
    let mut index: HashMap<&str, usize> = HashMap::new();
    for (i, name) in header.iter().enumerate() {
        if index.insert(name, i).is_some() {
            return Err(FormatError::new(
                path,
                Some("line 1".into()),
                format!("column `{name}` appears twice"),
            ));
        }
    }
    let column = |name: &str| index.get(name).copied();
    let pixel_cols: Vec<usize> = PIXEL_COLUMNS
        .iter()
        .map(|c| {
            column(c).ok_or_else(|| {
                FormatError::new(path, Some("line 1".into()), format!("missing column `{c}`"))
            })
        })
        .collect::<Result<_, _>>()?;
    let model_cols: Vec<Option<usize>> = MODEL_COLUMNS.iter().map(|c| column(c)).collect();
    let model_cols: Option<Vec<usize>> = match model_cols.iter().filter(|c| c.is_some()).count() {
        0 => None,
        3 => Some(model_cols.into_iter().flatten().collect()),
        _ => {
            return Err(FormatError::new(
                path,
                Some("line 1".into()),
                "give all of `jx`, `jy`, `jz` or none",
            ));
        }
    };
    let joint_cols: Vec<usize> = (0..).map_while(|i| column(&format!("q{i}"))).collect();
    if let Some(extra) = header.iter().find(|h| {
        h.strip_prefix('q')
            .is_some_and(|n| n.parse::<usize>().is_ok_and(|n| n >= joint_cols.len()))
    }) {
        return Err(FormatError::new(
            path,
            Some("line 1".into()),
            format!(
                "joint column `{extra}` without `q{}`: joint columns must run q0, q1, ...",
                joint_cols.len()
            ),
        ));
    }
    if let Some(dof) = arm_dof
        && !joint_cols.is_empty()
        && joint_cols.len() != dof
    {
        return Err(FormatError::new(
            path,
            Some("line 1".into()),
            format!(
                "{} joint columns (q0..q{}) but the rig's arm has {dof} joints",
                joint_cols.len(),
                joint_cols.len() - 1
            ),
        ));
    }
    let pose_col = column("pose");
    let view_col = column("view");

    let mut samples = Vec::new();
    for (row, record) in reader.records().enumerate() {
        let record = record.map_err(|e| {
            let line = e.position().map(|p| format!("line {}", p.line()));
            FormatError::new(path, line, e.to_string())
        })?;
        let line = record.position().map_or(row as u64 + 2, |p| p.line());
        let at = || Some(format!("line {line}"));
        let number = |col: usize| -> Result<f64, FormatError> {
            let cell = record.get(col).unwrap_or("");
            let v: f64 = cell.parse().map_err(|_| {
                FormatError::new(
                    path,
                    at(),
                    format!("column `{}`: `{cell}` is not a number", &header[col]),
                )
            })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(FormatError::new(
                    path,
                    at(),
                    format!("column `{}`: `{cell}` is not finite", &header[col]),
                ))
            }
        };
        let pose = match pose_col {
            Some(c) => {
                let cell = record.get(c).unwrap_or("");
                cell.parse::<u64>().map_err(|_| {
                    FormatError::new(
                        path,
                        at(),
                        format!("column `pose`: `{cell}` is not a non-negative integer"),
                    )
                })?
            }
            None => row as u64,
        };
        let view = match view_col.map(|c| record.get(c).unwrap_or("")) {
            None | Some("mirror") => View::Mirror,
            Some("direct") => View::Direct,
            Some(other) => {
                return Err(FormatError::new(
                    path,
                    at(),
                    format!("column `view`: `{other}` is neither `mirror` nor `direct`"),
                ));
            }
        };
        let joints = if joint_cols.is_empty() {
            None
        } else {
            Some(
                joint_cols
                    .iter()
                    .map(|&c| number(c))
                    .collect::<Result<Vec<_>, _>>()?,
            )
        };
        let model_point = match &model_cols {
            Some(c) => Some(Vector3::new(number(c[0])?, number(c[1])?, number(c[2])?)),
            None => None,
        };
        let px: Vec<f64> = pixel_cols
            .iter()
            .map(|&c| number(c))
            .collect::<Result<_, _>>()?;
        samples.push(Sample {
            pose,
            view,
            joints,
            model_point,
            pixels: [Vector2::new(px[0], px[1]), Vector2::new(px[2], px[3])],
        });
    }
    Ok(samples)
}

/// Renders samples as CSV. Every sample must have the same kind of content
/// (joints of one length or none; model points or none).
pub fn to_csv(samples: &[Sample]) -> String {
    let dof = samples
        .iter()
        .find_map(|s| s.joints.as_ref().map(Vec::len))
        .unwrap_or(0);
    let with_model = samples.iter().any(|s| s.model_point.is_some());
    let mut out = String::from("pose,view");
    for i in 0..dof {
        out += &format!(",q{i}");
    }
    if with_model {
        out += ",jx,jy,jz";
    }
    out += ",left_u,left_v,right_u,right_v\n";
    for s in samples {
        out += &format!("{},{}", s.pose, s.view.as_str());
        let q = s.joints.clone().unwrap_or_default();
        for i in 0..dof {
            out += &format!(",{}", q.get(i).copied().unwrap_or(f64::NAN));
        }
        if with_model {
            let j = s.model_point.unwrap_or(Vector3::repeat(f64::NAN));
            out += &format!(",{},{},{}", j.x, j.y, j.z);
        }
        let [l, r] = s.pixels;
        out += &format!(",{},{},{},{}\n", l.x, l.y, r.x, r.y);
    }
    out
}

/// Writes a samples file.
pub fn write(path: impl AsRef<Path>, samples: &[Sample]) -> Result<(), FormatError> {
    write_text(path.as_ref(), &to_csv(samples))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse_str(text: &str, dof: Option<usize>) -> Result<Vec<Sample>, String> {
        parse(Path::new("s.csv"), text.as_bytes(), dof).map_err(|e| e.to_string())
    }

    #[test]
    fn round_trips_and_accepts_any_column_order() {
        let s = Sample {
            pose: 3,
            view: View::Direct,
            joints: Some(vec![0.1, -0.2, 0.3, 0.123456789012345]),
            model_point: Some(Vector3::new(1.5, -2.25, 300.125)),
            pixels: [Vector2::new(100.5, 200.25), Vector2::new(90.0, 201.0)],
        };
        let back = parse_str(&to_csv(std::slice::from_ref(&s)), Some(4)).unwrap();
        assert_eq!(back, vec![s]);
        let shuffled = "right_v,left_u,right_u,left_v\n4,1,3,2\n";
        let got = parse_str(shuffled, None).unwrap();
        assert_eq!(
            got[0].pixels,
            [Vector2::new(1.0, 2.0), Vector2::new(3.0, 4.0)]
        );
        assert_eq!(got[0].view, View::Mirror);
    }

    #[test]
    fn bad_files_name_the_line_and_column() {
        let e = parse_str("pose,left_u,left_v,right_u\n0,1,2,3\n", None).unwrap_err();
        assert_eq!(e, "s.csv: line 1: missing column `right_v`");
        let e = parse_str("left_u,left_v,right_u,right_v\n1,2,3,4\n1,NaN,3,4\n", None).unwrap_err();
        assert_eq!(e, "s.csv: line 3: column `left_v`: `NaN` is not finite");
        let e = parse_str("left_u,left_v,right_u,right_v\n1,2,x,4\n", None).unwrap_err();
        assert_eq!(e, "s.csv: line 2: column `right_u`: `x` is not a number");
        let e = parse_str(
            "q0,q1,q2,left_u,left_v,right_u,right_v\n0,0,0,1,2,3,4\n",
            Some(4),
        )
        .unwrap_err();
        assert_eq!(
            e,
            "s.csv: line 1: 3 joint columns (q0..q2) but the rig's arm has 4 joints"
        );
        let e = parse_str("q0,q2,left_u,left_v,right_u,right_v\n0,0,1,2,3,4\n", None).unwrap_err();
        assert!(e.contains("`q2` without `q1`"), "{e}");
        let e = parse_str("view,left_u,left_v,right_u,right_v\nside,1,2,3,4\n", None).unwrap_err();
        assert!(e.starts_with("s.csv: line 2: column `view`"), "{e}");
        let e = parse_str("left_u,left_v,right_u,right_v\n1,2,3\n", None).unwrap_err();
        assert!(e.starts_with("s.csv: line 2"), "{e}");
    }
}
