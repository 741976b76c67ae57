//! Real footage: directories of image pairs, video files, camera devices.

use std::path::{Path, PathBuf};

use opencv::prelude::*;
use opencv::{core, imgcodecs, imgproc, videoio};

use crate::CameraError;

/// A source of stereo mono8 image pairs.
pub trait StereoSource {
    /// Width and height of each image.
    fn size(&self) -> (u32, u32);
    /// Reads the next pair into `left` and `right` (width x height bytes each);
    /// `false` at the end.
    fn next_into(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<bool, CameraError>;
}

/// Copies a decoded image (any depth/channels) as mono8 into `out`.
fn to_mono_into(image: &Mat, out: &mut [u8], what: &str) -> Result<(), CameraError> {
    let mut grey = Mat::default();
    match image.channels() {
        1 => grey = image.clone(),
        3 => imgproc::cvt_color(image, &mut grey, imgproc::COLOR_BGR2GRAY, 0)?,
        4 => imgproc::cvt_color(image, &mut grey, imgproc::COLOR_BGRA2GRAY, 0)?,
        channels => {
            return Err(CameraError::Channels {
                what: what.to_string(),
                channels,
            });
        }
    }
    let bytes = grey.data_bytes()?;
    if bytes.len() != out.len() {
        return Err(CameraError::ImageBytes {
            what: what.to_string(),
            bytes: bytes.len(),
            expected: out.len(),
        });
    }
    out.copy_from_slice(bytes);
    Ok(())
}

/// Image pairs from a directory: `*left*`/`*right*` files sorted by name
/// (e.g. `0001_left.png`, `0001_right.png`).
pub struct ImagePairs {
    pairs: Vec<(PathBuf, PathBuf)>,
    next: usize,
    size: (u32, u32),
}

impl ImagePairs {
    /// Lists the pairs of `dir` and reads the first to learn the size.
    pub fn open(dir: &Path) -> Result<Self, CameraError> {
        let cannot_list = |source| CameraError::List {
            dir: dir.to_path_buf(),
            source,
        };
        let mut lefts = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(cannot_list)? {
            let path = entry.map_err(cannot_list)?.path();
            let name = path
                .file_name()
                .and_then(|n| n.to_str())
                .unwrap_or("")
                .to_string();
            if name.contains("left") {
                let right = path.with_file_name(name.replacen("left", "right", 1));
                if !right.exists() {
                    return Err(CameraError::NoRightImage { left: path, right });
                }
                lefts.push((path, right));
            }
        }
        lefts.sort();
        let first = lefts.first().ok_or_else(|| CameraError::NoLeftImages {
            dir: dir.to_path_buf(),
        })?;
        let img = imgcodecs::imread(&first.0, imgcodecs::IMREAD_GRAYSCALE)?;
        if img.empty() {
            return Err(CameraError::Undecodable {
                path: first.0.clone(),
            });
        }
        Ok(Self {
            size: (img.cols() as u32, img.rows() as u32),
            pairs: lefts,
            next: 0,
        })
    }
}

impl StereoSource for ImagePairs {
    fn size(&self) -> (u32, u32) {
        self.size
    }

    fn next_into(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<bool, CameraError> {
        let Some((l, r)) = self.pairs.get(self.next).cloned() else {
            return Ok(false);
        };
        self.next += 1;
        for (path, out) in [(&l, left), (&r, right)] {
            let img = imgcodecs::imread(path, imgcodecs::IMREAD_UNCHANGED)?;
            if img.empty() {
                return Err(CameraError::Undecodable { path: path.clone() });
            }
            if (img.cols() as u32, img.rows() as u32) != self.size {
                return Err(CameraError::SizeDiffers {
                    path: path.clone(),
                    width: img.cols(),
                    height: img.rows(),
                });
            }
            to_mono_into(&img, out, &path.display().to_string())?;
        }
        Ok(true)
    }
}

/// What a capture says about itself when opened.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureInfo {
    /// Frame size as delivered (both halves for side by side), px.
    pub width: u32,
    /// Frame height, px.
    pub height: u32,
    /// The frame rate it declares, Hz (0 when it declares none).
    pub fps: f64,
    /// Its codec's FourCC, e.g. `MJPG` (empty when none is declared).
    pub codec: String,
    /// Frames in a file; `None` for a live device.
    pub frames: Option<u64>,
}

fn open_capture(source: &str) -> Result<(videoio::VideoCapture, CaptureInfo), CameraError> {
    let cap = videoio::VideoCapture::from_file(source, videoio::CAP_ANY)?;
    if !cap.is_opened()? {
        return Err(CameraError::CannotOpen {
            capture: source.to_string(),
        });
    }
    let fourcc = cap.get(videoio::CAP_PROP_FOURCC)? as u32;
    let codec: String = fourcc
        .to_le_bytes()
        .iter()
        .filter(|b| b.is_ascii_graphic())
        .map(|&b| b as char)
        .collect();
    let count = cap.get(videoio::CAP_PROP_FRAME_COUNT)?;
    let info = CaptureInfo {
        width: cap.get(videoio::CAP_PROP_FRAME_WIDTH)? as u32,
        height: cap.get(videoio::CAP_PROP_FRAME_HEIGHT)? as u32,
        fps: cap.get(videoio::CAP_PROP_FPS)?.max(0.0),
        codec,
        frames: (count > 0.0).then_some(count as u64),
    };
    tracing::info!(
        source,
        width = info.width,
        height = info.height,
        fps = info.fps,
        codec = info.codec.as_str(),
        frames = info.frames,
        "opened"
    );
    Ok((cap, info))
}

/// One side-by-side capture (a video file or a device) split into left and right halves,
/// or two captures (two devices).
pub struct Captures {
    captures: Vec<videoio::VideoCapture>,
    size: (u32, u32),
    name: String,
    info: CaptureInfo,
}

impl Captures {
    /// Opens a video file or device path (`/dev/video0`) holding side-by-side stereo.
    pub fn side_by_side(source: &str) -> Result<Self, CameraError> {
        let (cap, info) = open_capture(source)?;
        if info.width < 2 || info.width % 2 != 0 {
            return Err(CameraError::NotSideBySide {
                capture: source.to_string(),
                width: info.width,
            });
        }
        Ok(Self {
            captures: vec![cap],
            size: (info.width / 2, info.height),
            name: source.into(),
            info,
        })
    }

    /// Opens two devices or files, left then right.
    pub fn pair(left: &str, right: &str) -> Result<Self, CameraError> {
        let (l, info) = open_capture(left)?;
        let (r, right_info) = open_capture(right)?;
        if (right_info.width, right_info.height) != (info.width, info.height) {
            return Err(CameraError::PairSizes {
                left: left.to_string(),
                right: right.to_string(),
                left_size: (info.width, info.height),
                right_size: (right_info.width, right_info.height),
            });
        }
        Ok(Self {
            captures: vec![l, r],
            size: (info.width, info.height),
            name: format!("{left} + {right}"),
            info,
        })
    }

    /// What the (left) capture declared when opened.
    pub fn info(&self) -> &CaptureInfo {
        &self.info
    }

    /// The rate to play at: a file's own frame rate; `None` for a live
    /// device, which delivers at its own pace.
    pub fn file_rate(&self) -> Option<f64> {
        self.info
            .frames
            .and_then(|_| (self.info.fps > 0.0).then_some(self.info.fps))
    }
}

impl StereoSource for Captures {
    fn size(&self) -> (u32, u32) {
        self.size
    }

    fn next_into(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<bool, CameraError> {
        let mut frames = Vec::new();
        for cap in &mut self.captures {
            let mut m = Mat::default();
            if !cap.read(&mut m)? || m.empty() {
                return Ok(false);
            }
            frames.push(m);
        }
        if frames.len() == 1 {
            let (w, h) = (self.size.0 as i32, self.size.1 as i32);
            let l = Mat::roi(&frames[0], core::Rect::new(0, 0, w, h))?.try_clone()?;
            let r = Mat::roi(&frames[0], core::Rect::new(w, 0, w, h))?.try_clone()?;
            to_mono_into(&l, left, &self.name)?;
            to_mono_into(&r, right, &self.name)?;
        } else {
            to_mono_into(&frames[0], left, &self.name)?;
            to_mono_into(&frames[1], right, &self.name)?;
        }
        Ok(true)
    }
}
