//! `sensor_msgs/Image` without copying its pixels: the fields read from the
//! CDR payload, the pixels borrowed from it ([`ImageView`]), converted to
//! our mono8 straight into the frame in shared memory ([`write_mono`]).

use byteorder::{BigEndian, ByteOrder, LittleEndian};
use serde::Deserialize;

use crate::msgs::Header;
use crate::wire::WireError;

/// Bytes that may lie in several pieces: a zenoh payload that arrived in
/// fragments is a list of slices, and is read where it lies rather than
/// gathered into one buffer first (which would copy every image once more).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Pieces<'a> {
    pieces: Vec<&'a [u8]>,
    len: usize,
}

impl<'a> Pieces<'a> {
    /// The pieces, in order.
    pub fn new(pieces: impl IntoIterator<Item = &'a [u8]>) -> Self {
        let pieces: Vec<&[u8]> = pieces.into_iter().filter(|p| !p.is_empty()).collect();
        let len = pieces.iter().map(|p| p.len()).sum();
        Pieces { pieces, len }
    }

    /// Total length.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are no bytes.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The bytes from `start` on (`start` at most [`Pieces::len`]).
    fn from(&self, mut start: usize) -> Pieces<'a> {
        let mut rest = Vec::with_capacity(self.pieces.len());
        for p in &self.pieces {
            if start >= p.len() {
                start -= p.len();
            } else {
                rest.push(&p[start..]);
                start = 0;
            }
        }
        Pieces::new(rest)
    }

    /// The first `len` bytes (`len` at most [`Pieces::len`]).
    fn take(&self, mut len: usize) -> Pieces<'a> {
        let mut kept = Vec::with_capacity(self.pieces.len());
        for p in &self.pieces {
            if len == 0 {
                break;
            }
            let n = p.len().min(len);
            kept.push(&p[..n]);
            len -= n;
        }
        Pieces::new(kept)
    }

    /// Copies `out.len()` bytes from `offset` into `out`.
    pub fn copy_to(&self, offset: usize, out: &mut [u8]) {
        let mut skip = offset;
        let mut written = 0;
        for p in &self.pieces {
            if written == out.len() {
                break;
            }
            if skip >= p.len() {
                skip -= p.len();
                continue;
            }
            let n = (p.len() - skip).min(out.len() - written);
            out[written..written + n].copy_from_slice(&p[skip..skip + n]);
            written += n;
            skip = 0;
        }
    }

    /// `len` bytes from `offset`: borrowed when they lie in one piece,
    /// else gathered into `scratch` (a row across a fragment boundary).
    fn slice<'s>(&'s self, offset: usize, len: usize, scratch: &'s mut Vec<u8>) -> &'s [u8] {
        let mut at = offset;
        for p in &self.pieces {
            if at < p.len() {
                if at + len <= p.len() {
                    return &p[at..at + len];
                }
                break;
            }
            at -= p.len();
        }
        scratch.resize(len, 0);
        self.copy_to(offset, scratch);
        scratch
    }

    /// The pieces, in order.
    pub fn pieces(&self) -> &[&'a [u8]] {
        &self.pieces
    }

    /// The bytes as one vector (tests).
    pub fn to_vec(&self) -> Vec<u8> {
        let mut v = vec![0; self.len];
        self.copy_to(0, &mut v);
        v
    }
}

/// An `Image` whose `data` is borrowed from the payload it came in.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageView<'a> {
    /// Capture stamp and camera frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`mono8`, `rgb8`, `bgr8`, ...).
    pub encoding: String,
    /// Byte order of multi-byte pixels.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// The pixels, where they lie in the payload.
    pub data: Pieces<'a>,
}

/// Every field of `Image` before `data`, in order.
#[derive(Deserialize)]
struct Fields {
    header: Header,
    height: u32,
    width: u32,
    encoding: String,
    is_bigendian: u8,
    step: u32,
}

/// Bytes of a payload's start gathered to read the fields when its first
/// fragment is shorter than they are (a frame id this long is not sent).
const MAX_FIELDS: usize = 64 * 1024;

impl<'a> ImageView<'a> {
    /// Reads a CDR payload in one piece (with its encapsulation header,
    /// either byte order).
    pub fn parse(payload: &'a [u8]) -> Result<Self, WireError> {
        Self::parse_pieces(Pieces::new([payload]))
    }

    /// Reads a CDR payload that may lie in pieces. The codec reads the
    /// fields; the pixels' `uint8[]` (a `u32` count at 4-byte alignment,
    /// then the bytes) stays where it lies, not decoded byte by byte.
    pub fn parse_pieces(payload: Pieces<'a>) -> Result<Self, WireError> {
        let mut head = [0u8; 4];
        if payload.len() < 4 {
            return Err(WireError::NoHeader(payload.len()));
        }
        payload.copy_to(0, &mut head);
        let body = payload.from(4);
        match (head[0], head[1]) {
            (0, 1) => Self::parse_body::<LittleEndian>(body),
            (0, 0) => Self::parse_body::<BigEndian>(body),
            (a, b) => Err(WireError::Encapsulation(a, b)),
        }
    }

    fn parse_body<BO: ByteOrder>(body: Pieces<'a>) -> Result<Self, WireError> {
        // The fields lie in the first piece but for a pathological
        // fragmentation; then the payload's start is gathered to read them.
        let in_first = body
            .pieces
            .first()
            .map(|p| cdr_encoding::from_bytes::<Fields, BO>(p));
        let (fields, used) = match in_first {
            Some(Ok(read)) => read,
            _ => cdr_encoding::from_bytes::<Fields, BO>(&body.take(MAX_FIELDS).to_vec())?,
        };
        // Alignment counts from the end of the encapsulation header.
        let count_at = used.next_multiple_of(4);
        let present = body.len().saturating_sub(count_at + 4);
        let short = |declared| WireError::Short {
            what: "Image.data",
            declared,
            present,
        };
        let mut count = [0u8; 4];
        if body.len() < count_at + 4 {
            return Err(short(4));
        }
        body.copy_to(count_at, &mut count);
        let count = BO::read_u32(&count) as usize;
        if count > present {
            return Err(short(count));
        }
        Ok(ImageView {
            header: fields.header,
            height: fields.height,
            width: fields.width,
            encoding: fields.encoding,
            is_bigendian: fields.is_bigendian,
            step: fields.step,
            data: body.from(count_at + 4).take(count),
        })
    }
}

/// The pixel encodings we read (`sensor_msgs/image_encodings.hpp`'s names).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    /// `mono8` (and `8UC1`): grey as is.
    Mono8,
    /// `rgb8`.
    Rgb8,
    /// `bgr8`.
    Bgr8,
    /// `rgba8`.
    Rgba8,
    /// `bgra8`.
    Bgra8,
}

impl PixelFormat {
    /// The encodings we read, for messages.
    pub const NAMES: &'static str = "mono8, 8UC1, rgb8, bgr8, rgba8, bgra8";

    /// The format of an encoding name, if we read it.
    pub fn of(encoding: &str) -> Option<PixelFormat> {
        Some(match encoding {
            "mono8" | "8UC1" => PixelFormat::Mono8,
            "rgb8" => PixelFormat::Rgb8,
            "bgr8" => PixelFormat::Bgr8,
            "rgba8" => PixelFormat::Rgba8,
            "bgra8" => PixelFormat::Bgra8,
            _ => return None,
        })
    }

    /// Bytes per pixel.
    pub fn channels(self) -> usize {
        match self {
            PixelFormat::Mono8 => 1,
            PixelFormat::Rgb8 | PixelFormat::Bgr8 => 3,
            PixelFormat::Rgba8 | PixelFormat::Bgra8 => 4,
        }
    }
}

/// Why an image cannot become a frame.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ImageError {
    /// An encoding we do not read.
    #[error("encoding {0:?} is not supported (we read {names})", names = PixelFormat::NAMES)]
    Encoding(String),
    /// A size other than the frame's.
    #[error("{width}x{height} px, the stream's frames are {frame_width}x{frame_height}")]
    Size {
        /// The image's width.
        width: u32,
        /// Its height.
        height: u32,
        /// The frames' width.
        frame_width: u32,
        /// Their height.
        frame_height: u32,
    },
    /// Fewer bytes than its size, encoding and step need.
    #[error("{width}x{height} {encoding} with step {step} needs {needed} bytes, it has {bytes}")]
    Bytes {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Encoding.
        encoding: String,
        /// Row step.
        step: u32,
        /// Bytes needed.
        needed: usize,
        /// Bytes present.
        bytes: usize,
    },
}

impl ImageView<'_> {
    /// Its pixel format, checked against its size, step and data.
    pub fn format(&self) -> Result<PixelFormat, ImageError> {
        let format = PixelFormat::of(&self.encoding)
            .ok_or_else(|| ImageError::Encoding(self.encoding.clone()))?;
        let (w, h, step) = (
            self.width as usize,
            self.height as usize,
            self.step as usize,
        );
        let row = w * format.channels();
        let needed = if h == 0 { 0 } else { step * (h - 1) + row };
        if step < row || self.data.len() < needed || w == 0 || h == 0 {
            return Err(ImageError::Bytes {
                width: self.width,
                height: self.height,
                encoding: self.encoding.clone(),
                step: self.step,
                needed: needed.max(row * h),
                bytes: self.data.len(),
            });
        }
        Ok(format)
    }
}

/// OpenCV's fixed-point luma (`cv::cvtColor` `RGB2GRAY` on 8-bit images,
/// `imgproc/src/color.hpp`: `R2Y = 4899, G2Y = 9617, B2Y = 1868`, 14-bit
/// shift, rounded), so a colour stream gives the same grey as our file and
/// device sources, which convert with OpenCV.
fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((u32::from(r) * 4899 + u32::from(g) * 9617 + u32::from(b) * 1868 + (1 << 13)) >> 14) as u8
}

/// Writes `image` (whose [`ImageView::format`] is `format`) as mono8 into
/// `out`, `width * height` bytes: a row copy for grey, a conversion for
/// colour. This is the only copy of the pixels on their way to the frame.
pub fn write_mono(image: &ImageView<'_>, format: PixelFormat, out: &mut [u8]) {
    let (w, step) = (image.width as usize, image.step as usize);
    let channels = format.channels();
    if format == PixelFormat::Mono8 && step == w {
        image.data.copy_to(0, out);
        return;
    }
    let mut scratch = Vec::new();
    for (y, out_row) in out.chunks_exact_mut(w).enumerate() {
        if format == PixelFormat::Mono8 {
            image.data.copy_to(y * step, out_row);
            continue;
        }
        let row = image.data.slice(y * step, w * channels, &mut scratch);
        match format {
            PixelFormat::Mono8 => unreachable!("copied above"),
            PixelFormat::Rgb8 => luma_row::<0, 2, 3>(row, out_row),
            PixelFormat::Bgr8 => luma_row::<2, 0, 3>(row, out_row),
            PixelFormat::Rgba8 => luma_row::<0, 2, 4>(row, out_row),
            PixelFormat::Bgra8 => luma_row::<2, 0, 4>(row, out_row),
        }
    }
}

/// One row's luma, with the layout fixed at compile time so that the loop
/// vectorises (a run-time channel order cost 3x, measured in `ros2_hop`).
fn luma_row<const RED: usize, const BLUE: usize, const CHANNELS: usize>(
    row: &[u8],
    out: &mut [u8],
) {
    for (o, px) in out.iter_mut().zip(row.chunks_exact(CHANNELS)) {
        *o = luma(px[RED], px[1], px[BLUE]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Image, Time};
    use crate::wire;

    fn image(encoding: &str, width: u32, height: u32, step: u32) -> Image {
        Image {
            header: Header {
                stamp: Time {
                    sec: 12,
                    nanosec: 345,
                },
                frame_id: "left_optical".into(),
            },
            height,
            width,
            encoding: encoding.into(),
            is_bigendian: 0,
            step,
            data: (0..step * height).map(|i| (i * 7 % 251) as u8).collect(),
        }
    }

    #[test]
    fn a_view_reads_what_the_codec_writes_with_the_pixels_borrowed() {
        // Frame ids of every length mod 4 move the alignment of what follows.
        for id in ["", "a", "ab", "abc", "abcd"] {
            let mut m = image("rgb8", 5, 3, 16);
            m.header.frame_id = id.into();
            let payload = wire::encode(&m).unwrap();
            let view = ImageView::parse(&payload).unwrap();
            assert_eq!(view.header, m.header);
            assert_eq!((view.width, view.height, view.step), (5, 3, 16));
            assert_eq!(view.encoding, "rgb8");
            assert_eq!(view.data.to_vec(), m.data);
            let pixels = view.data.pieces()[0];
            let start = pixels.as_ptr() as usize - payload.as_ptr() as usize;
            assert_eq!(&payload[start..start + pixels.len()], &m.data[..]);
        }
    }

    #[test]
    fn a_payload_in_fragments_reads_as_in_one_piece() {
        for (encoding, step) in [("mono8", 7), ("mono8", 9), ("bgr8", 21), ("rgba8", 30)] {
            let m = image(encoding, 7, 5, step);
            let payload = wire::encode(&m).unwrap();
            let whole = ImageView::parse(&payload).unwrap();
            let format = whole.format().unwrap();
            let mut expected = vec![0u8; 35];
            write_mono(&whole, format, &mut expected);
            // Cut in the fields, in the count, in rows, between rows.
            for cuts in [
                vec![3],
                vec![10, 40],
                vec![45, 46, 47, 48, 49],
                vec![50, 61, 75, 90],
            ] {
                let mut pieces = Vec::new();
                let mut at = 0;
                for c in cuts
                    .iter()
                    .copied()
                    .filter(|&c| c < payload.len())
                    .chain([payload.len()])
                {
                    pieces.push(&payload[at..c]);
                    at = c;
                }
                let view = ImageView::parse_pieces(Pieces::new(pieces)).unwrap();
                assert_eq!(view.data.to_vec(), m.data, "{encoding} {cuts:?}");
                assert_eq!((view.width, view.step), (7, step));
                let mut out = vec![0u8; 35];
                write_mono(&view, format, &mut out);
                assert_eq!(out, expected, "{encoding} {cuts:?}");
            }
        }
    }

    #[test]
    fn a_truncated_image_is_refused() {
        let payload = wire::encode(&image("mono8", 4, 4, 4)).unwrap();
        let cut = &payload[..payload.len() - 3];
        assert!(matches!(
            ImageView::parse(cut),
            Err(WireError::Short {
                declared: 16,
                present: 13,
                ..
            })
        ));
        assert!(ImageView::parse(&payload[..30]).is_err());
    }

    #[test]
    fn formats_check_their_size_and_step() {
        let payload = wire::encode(&image("bgr8", 4, 2, 12)).unwrap();
        assert_eq!(
            ImageView::parse(&payload).unwrap().format(),
            Ok(PixelFormat::Bgr8)
        );
        let short_step = wire::encode(&image("bgr8", 4, 2, 11)).unwrap();
        assert!(matches!(
            ImageView::parse(&short_step).unwrap().format(),
            Err(ImageError::Bytes { .. })
        ));
        let yuv = wire::encode(&image("yuv422", 4, 2, 8)).unwrap();
        let e = ImageView::parse(&yuv).unwrap().format().unwrap_err();
        assert_eq!(
            e.to_string(),
            "encoding \"yuv422\" is not supported (we read mono8, 8UC1, rgb8, bgr8, rgba8, bgra8)"
        );
    }

    #[test]
    fn padded_rows_are_read_without_their_padding() {
        let m = image("mono8", 3, 2, 5);
        let payload = wire::encode(&m).unwrap();
        let view = ImageView::parse(&payload).unwrap();
        let mut out = [0u8; 6];
        write_mono(&view, view.format().unwrap(), &mut out);
        assert_eq!(out[..3], m.data[..3]);
        assert_eq!(out[3..], m.data[5..8]);
    }

    #[test]
    fn colour_becomes_the_grey_opencv_makes() {
        use opencv::core::Mat;
        use opencv::imgproc;
        use opencv::prelude::*;
        let (w, h) = (37, 11);
        let pixels: Vec<u8> = (0..w * h * 3).map(|i| (i * 97 % 256) as u8).collect();
        for (encoding, code) in [
            ("rgb8", imgproc::COLOR_RGB2GRAY),
            ("bgr8", imgproc::COLOR_BGR2GRAY),
        ] {
            let m = Image {
                encoding: encoding.into(),
                width: w as u32,
                height: h as u32,
                step: (w * 3) as u32,
                data: pixels.clone(),
                ..Default::default()
            };
            let payload = wire::encode(&m).unwrap();
            let view = ImageView::parse(&payload).unwrap();
            let mut ours = vec![0u8; w * h];
            write_mono(&view, view.format().unwrap(), &mut ours);
            let flat = Mat::from_slice(&pixels).unwrap();
            let colour = flat.reshape(3, h as i32).unwrap();
            let mut grey = Mat::default();
            imgproc::cvt_color(&colour, &mut grey, code, 0).unwrap();
            assert_eq!(ours, grey.data_bytes().unwrap(), "{encoding}");
        }
    }
}
