//! Camera calibration files: image size, camera matrix and distortion, as
//! the two common tools write them.
//!
//! - ROS `camera_info` YAML (`camera_calibration`'s `ost.yaml`,
//!   `camera_info_manager`):
//!
//!   ```yaml
//!   image_width: 640
//!   image_height: 480
//!   camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
//!   distortion_model: plumb_bob          # or rational_polynomial
//!   distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}
//!   ```
//!
//! - OpenCV FileStorage YAML (`%YAML:1.0`, as OpenCV's calibration sample
//!   and `cv::FileStorage` write it), with `!!opencv-matrix` nodes
//!   `camera_matrix` and `distortion_coefficients` (`rows`, `cols`, `dt`,
//!   `data`) and `image_width`, `image_height`.
//!
//! Other keys (rectification, projection, reprojection error, …) are
//! ignored; the camera's pose is not in these files (it stays in the rig).

use std::path::Path;

use geometry::{Distortion, DistortionModel, Intrinsics};
use yaml_rust2::{Yaml, YamlLoader};

use crate::{FormatError, read_text};

/// Which kind of file it was.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraFileKind {
    /// A ROS `camera_info` YAML.
    RosCameraInfo,
    /// An OpenCV FileStorage YAML.
    OpenCv,
}

/// Reads a camera calibration file of either kind.
pub fn read(path: impl AsRef<Path>) -> Result<(Intrinsics, CameraFileKind), FormatError> {
    let path = path.as_ref();
    parse(path, &read_text(path)?)
}

/// Parses calibration file text; `path` is only used in error messages.
pub fn parse(path: &Path, text: &str) -> Result<(Intrinsics, CameraFileKind), FormatError> {
    // OpenCV writes the YAML 1.0 directive as `%YAML:1.0`, which YAML
    // parsers reject; the colon form is OpenCV's alone.
    let (text, kind) = match text.strip_prefix("%YAML:1.0") {
        Some(rest) => (format!("%YAML 1.0{rest}"), CameraFileKind::OpenCv),
        None if text.contains("!!opencv-matrix") => (text.to_string(), CameraFileKind::OpenCv),
        None => (text.to_string(), CameraFileKind::RosCameraInfo),
    };
    let docs = YamlLoader::load_from_str(&text).map_err(|e| {
        FormatError::new(
            path,
            Some(format!("line {}", e.marker().line())),
            e.info().to_string(),
        )
    })?;
    let root = docs
        .first()
        .filter(|d| d.as_hash().is_some())
        .ok_or_else(|| {
            FormatError::new(path, None, "expected a YAML mapping with camera_matrix")
        })?;
    let size = |key: &str| -> Result<u32, FormatError> {
        match &root[key] {
            Yaml::Integer(v) if *v > 0 && *v <= i64::from(u32::MAX) => Ok(*v as u32),
            Yaml::BadValue => Err(FormatError::at_key(path, key, "missing")),
            _ => Err(FormatError::at_key(path, key, "must be a positive integer")),
        }
    };
    let (width, height) = (size("image_width")?, size("image_height")?);
    let k = matrix(path, root, "camera_matrix")?;
    if k.rows != 3 || k.cols != 3 {
        return Err(FormatError::at_key(
            path,
            "camera_matrix",
            format!("must be 3x3, found {}x{}", k.rows, k.cols),
        ));
    }
    let m = &k.data;
    if m[3] != 0.0 || m[6] != 0.0 || m[7] != 0.0 || (m[8] - 1.0).abs() > 1e-12 {
        return Err(FormatError::at_key(
            path,
            "camera_matrix",
            "is not a camera matrix [fx, s, cx; 0, fy, cy; 0, 0, 1]",
        ));
    }
    if !(m[0] > 0.0 && m[4] > 0.0) {
        return Err(FormatError::at_key(
            path,
            "camera_matrix",
            "focal lengths must be positive",
        ));
    }
    let coefficients = match &root["distortion_coefficients"] {
        Yaml::BadValue => Vec::new(),
        _ => {
            let d = matrix(path, root, "distortion_coefficients")?;
            if d.rows != 1 && d.cols != 1 {
                return Err(FormatError::at_key(
                    path,
                    "distortion_coefficients",
                    format!("must be one row or one column, found {}x{}", d.rows, d.cols),
                ));
            }
            d.data
        }
    };
    let model = match &root["distortion_model"] {
        Yaml::BadValue => None,
        Yaml::String(s) => Some(match s.as_str() {
            "plumb_bob" => DistortionModel::PlumbBob,
            "rational_polynomial" => DistortionModel::RationalPolynomial,
            other => {
                return Err(FormatError::at_key(
                    path,
                    "distortion_model",
                    format!(
                        "unknown distortion model {other:?}; expected plumb_bob or rational_polynomial"
                    ),
                ));
            }
        }),
        _ => {
            return Err(FormatError::at_key(
                path,
                "distortion_model",
                "must be a string",
            ));
        }
    };
    let most = model.map_or(8, DistortionModel::coefficient_count);
    if coefficients.len() > most {
        return Err(FormatError::at_key(
            path,
            "distortion_coefficients",
            format!(
                "{} coefficients, more than the {} of {}",
                coefficients.len(),
                most,
                model.map_or("OpenCV's rational model", DistortionModel::ros_name)
            ),
        ));
    }
    let dist = Distortion::from_opencv(&coefficients)
        .map_err(|e| FormatError::at_key(path, "distortion_coefficients", e.to_string()))?;
    Ok((
        Intrinsics {
            width,
            height,
            fx: m[0],
            fy: m[4],
            skew: m[1],
            cx: m[2],
            cy: m[5],
            dist,
        },
        kind,
    ))
}

struct YamlMatrix {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

fn matrix(path: &Path, root: &Yaml, key: &str) -> Result<YamlMatrix, FormatError> {
    let node = &root[key];
    if node.is_badvalue() {
        return Err(FormatError::at_key(path, key, "missing"));
    }
    let dim = |k: &str| match &node[k] {
        Yaml::Integer(v) if *v > 0 && *v <= 64 => Ok(*v as usize),
        _ => Err(FormatError::at_key(
            path,
            format!("{key}.{k}"),
            "must be an integer from 1 to 64",
        )),
    };
    let (rows, cols) = (dim("rows")?, dim("cols")?);
    if let Yaml::String(dt) = &node["dt"]
        && !matches!(dt.as_str(), "d" | "f")
    {
        return Err(FormatError::at_key(
            path,
            format!("{key}.dt"),
            format!("element type {dt:?} is not a floating-point type (d or f)"),
        ));
    }
    let items = node["data"]
        .as_vec()
        .ok_or_else(|| FormatError::at_key(path, format!("{key}.data"), "must be a list"))?;
    let data = items
        .iter()
        .map(|v| match v {
            Yaml::Real(_) | Yaml::Integer(_) => v
                .as_f64()
                .or_else(|| v.as_i64().map(|i| i as f64))
                .filter(|f| f.is_finite()),
            _ => None,
        })
        .collect::<Option<Vec<f64>>>()
        .ok_or_else(|| {
            FormatError::at_key(path, format!("{key}.data"), "must hold finite numbers only")
        })?;
    if data.len() != rows * cols {
        return Err(FormatError::at_key(
            path,
            format!("{key}.data"),
            format!(
                "{} numbers for a {rows}x{cols} matrix (expected {})",
                data.len(),
                rows * cols
            ),
        ));
    }
    Ok(YamlMatrix { rows, cols, data })
}

/// Renders intrinsics as a ROS `camera_info` YAML (no rectification: `R`
/// is the identity and `P` is `K` with a zero fourth column).
pub fn to_ros_yaml(name: &str, k: &Intrinsics) -> String {
    let list = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let d = k.dist.coefficients();
    format!(
        "image_width: {}\nimage_height: {}\ncamera_name: {name}\n\
         camera_matrix:\n  rows: 3\n  cols: 3\n  data: [{}]\n\
         distortion_model: {}\n\
         distortion_coefficients:\n  rows: 1\n  cols: {}\n  data: [{}]\n\
         rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]\n\
         projection_matrix:\n  rows: 3\n  cols: 4\n  data: [{}]\n",
        k.width,
        k.height,
        list(&[k.fx, k.skew, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0]),
        k.dist.model().ros_name(),
        d.len(),
        list(&d),
        list(&[
            k.fx, k.skew, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0
        ]),
    )
}

#[cfg(test)]
#[allow(clippy::excessive_precision)] // the digits as OpenCV writes them
mod tests {
    use super::*;

    /// As OpenCV 4's `samples/cpp/calibration.cpp` writes it.
    const OPENCV: &str = "%YAML:1.0
---
calibration_time: \"Wed 08 Jun 2016 09:44:38 AM CEST\"
image_width: 640
image_height: 480
board_width: 9
board_height: 6
square_size: 1.
flags: 0
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 5.3591573396163199e+02, 0., 3.4228315473308373e+02, 0.,
       5.3591573396163199e+02, 2.3557082909788173e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -2.6637260909660682e-01, -3.8588898922304653e-02,
       1.7831947042852964e-03, -2.8122100441115472e-04,
       2.3839153080878486e-01 ]
avg_reprojection_error: 3.9259109564815318e-01
";

    /// As ROS's `camera_calibration` writes `ost.yaml`.
    const ROS: &str = "image_width: 1280
image_height: 720
camera_name: narrow_stereo/left
camera_matrix:
  rows: 3
  cols: 3
  data: [912.3, 0, 640.2, 0, 911.8, 360.4, 0, 0, 1]
distortion_model: rational_polynomial
distortion_coefficients:
  rows: 1
  cols: 8
  data: [0.41, -0.05, 0.0009, 0.0004, 0.002, 0.78, 0.06, 0.01]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [912.3, 0, 640.2, 0, 0, 911.8, 360.4, 0, 0, 0, 1, 0]
";

    fn p() -> &'static Path {
        Path::new("cam.yaml")
    }

    #[test]
    fn reads_an_opencv_calibration_sample_file() {
        let (k, kind) = parse(p(), OPENCV).unwrap();
        assert_eq!(kind, CameraFileKind::OpenCv);
        assert_eq!((k.width, k.height), (640, 480));
        assert_eq!(
            (k.fx, k.fy),
            (5.3591573396163199e+02, 5.3591573396163199e+02)
        );
        assert_eq!(
            (k.cx, k.cy, k.skew),
            (3.4228315473308373e+02, 2.3557082909788173e+02, 0.0)
        );
        assert_eq!(k.dist.p1, 1.7831947042852964e-03);
        assert_eq!(k.dist.k3, 2.3839153080878486e-01);
        assert_eq!(k.dist.model(), DistortionModel::PlumbBob);
    }

    #[test]
    fn reads_a_ros_camera_info_file_and_writes_one_back() {
        let (k, kind) = parse(p(), ROS).unwrap();
        assert_eq!(kind, CameraFileKind::RosCameraInfo);
        assert_eq!((k.width, k.height, k.fx, k.cy), (1280, 720, 912.3, 360.4));
        assert_eq!(
            k.dist.to_opencv(),
            [0.41, -0.05, 0.0009, 0.0004, 0.002, 0.78, 0.06, 0.01]
        );
        let (again, _) = parse(p(), &to_ros_yaml("left", &k)).unwrap();
        assert_eq!(again, k);
    }

    #[test]
    fn bad_files_get_one_line_errors_naming_the_key() {
        let cases = [
            (
                ROS.replace("cols: 3\n  data: [912.3", "cols: 2\n  data: [912.3"),
                "cam.yaml: key camera_matrix.data: 9 numbers for a 3x2 matrix",
            ),
            (
                ROS.replace("rational_polynomial", "equidistant"),
                "cam.yaml: key distortion_model: unknown distortion model \"equidistant\"",
            ),
            (
                ROS.replace("image_width: 1280\n", ""),
                "cam.yaml: key image_width: missing",
            ),
            (
                ROS.replace(
                    "rows: 3\n  cols: 3\n  data: [912.3, 0, 640.2, 0, 911.8, 360.4, 0, 0, 1]",
                    "rows: 2\n  cols: 2\n  data: [1, 0, 0, 1]",
                ),
                "cam.yaml: key camera_matrix: must be 3x3, found 2x2",
            ),
            (
                ROS.replace("rational_polynomial", "plumb_bob"),
                "cam.yaml: key distortion_coefficients: 8 coefficients, more than the 5 of plumb_bob",
            ),
            (
                ROS.replace("0.41, -0.05", "0.41, abc"),
                "cam.yaml: key distortion_coefficients.data: must hold finite numbers only",
            ),
            (
                ROS.replace("camera_matrix:\n  rows", "camera_matrix: [\n  rows"),
                "cam.yaml: line ",
            ),
            ("just text".to_string(), "cam.yaml: expected a YAML mapping"),
        ];
        for (text, expect) in cases {
            let e = parse(p(), &text).unwrap_err().to_string();
            assert!(e.starts_with(expect), "{e}\n  expected: {expect}");
            assert!(!e.contains('\n'), "{e}");
        }
    }
}
