//! Frame encodings for the viewer (DESIGN.md step 12, "Frames to the viewer"): the frame is
//! kept as linear RGB inside the renderer and leaves as sRGB 8-bit, raw or compressed as the
//! viewer asked — raw RGB8, QOI (lossless, fastest), PNG (lossless, fast compression level)
//! or JPEG (quality 90, smallest). QOI is encoded here (bands of rows in parallel, fused
//! with the conversion to sRGB); PNG and JPEG by the `image` crate. The linear encoding
//! (half floats, LZ4; [`linear`]) keeps the radiance for viewers that write EXR, feed tev or
//! tone-map themselves.
pub mod linear;
pub mod qoi;

use crate::srgb;
use edgepoint_proto::FrameEncoding;
use glam::Vec3;
use image::codecs::jpeg::JpegEncoder;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::codecs::qoi::QoiEncoder;
use image::{ExtendedColorType, ImageEncoder, ImageFormat};
use rayon::prelude::*;

/// JPEG quality used for `FRAME_ENCODING_JPEG`.
pub const JPEG_QUALITY: u8 = 90;

/// Why a frame could not be encoded or decoded.
#[derive(Debug, thiserror::Error)]
pub enum CodecError {
    #[error("frame is {width}x{height} but has {len} pixels")]
    SizeMismatch { width: u32, height: u32, len: usize },
    #[error("frame size {width}x{height} is not encodable as {encoding}")]
    BadSize { width: u32, height: u32, encoding: &'static str },
    #[error("{encoding} codec failed: {source}")]
    Image { encoding: &'static str, source: image::ImageError },
    #[error("decoded {encoding} frame is {got_w}x{got_h}, expected {width}x{height}")]
    DecodedSize { encoding: &'static str, got_w: u32, got_h: u32, width: u32, height: u32 },
    #[error("raw frame has {got} bytes, expected {expected}")]
    RawLength { got: usize, expected: usize },
    #[error("{encoding} frames are made from linear pixels, not from sRGB bytes")]
    NotFromSrgb { encoding: &'static str },
    #[error("{0}")]
    Linear(#[from] edgepoint_proto::linear_frame::LinearFrameError),
}

/// The encoding a request resolves to: `UNSPECIFIED` means QOI.
pub fn effective_encoding(e: FrameEncoding) -> FrameEncoding {
    match e {
        FrameEncoding::Unspecified => FrameEncoding::Qoi,
        other => other,
    }
}

fn name(e: FrameEncoding) -> &'static str {
    match effective_encoding(e) {
        FrameEncoding::RawRgb8 => "raw RGB8",
        FrameEncoding::Qoi => "QOI",
        FrameEncoding::Png => "PNG",
        FrameEncoding::Jpeg => "JPEG",
        FrameEncoding::LinearHalfLz4 => "linear half LZ4",
        FrameEncoding::Unspecified => unreachable!("resolved above"),
    }
}

/// Rows per band of the parallel conversion and QOI encoding: enough bands to share the
/// work among the cores (and let one core take over another's when the other is busy with
/// a shader worker), few enough that each band's restart costs nothing measurable.
const BAND_ROWS: usize = 16;

/// Converts a linear frame to interleaved sRGB8 bytes (bands of rows in parallel).
pub fn to_srgb8(linear: &[Vec3], width: u32, height: u32, out: &mut Vec<u8>) -> Result<(), CodecError> {
    check_size(linear, width, height)?;
    out.clear();
    out.resize(linear.len() * 3, 0);
    let w = width as usize;
    out.par_chunks_mut(w * 3 * BAND_ROWS).zip(linear.par_chunks(w * BAND_ROWS)).for_each(|(dst, src)| srgb::encode_row_rgb(src, dst));
    Ok(())
}

fn check_size(linear: &[Vec3], width: u32, height: u32) -> Result<(), CodecError> {
    let n = width as usize * height as usize;
    if linear.len() != n || n == 0 {
        return Err(CodecError::SizeMismatch { width, height, len: linear.len() });
    }
    Ok(())
}

/// One band's buffers, kept from frame to frame.
#[derive(Default)]
struct Band {
    /// The band's QOI bytes (the first `len`; the rest is working space).
    qoi: Vec<u8>,
    len: usize,
    /// One row of packed sRGB pixels.
    row: Vec<u32>,
}

/// Encodes frames for the wire, keeping its working buffers from frame to frame: after the
/// first frame of a size the only allocation per frame is the encoded frame it returns
/// (which leaves with the message). Conversion to sRGB and QOI encoding run in one pass
/// over bands of rows, the bands in parallel (see [`qoi`] for why bands can be encoded
/// apart).
#[derive(Default)]
pub struct FrameEncoder {
    bands: Vec<Band>,
    /// The sRGB bytes handed to the PNG and JPEG encoders.
    rgb: Vec<u8>,
    linear: linear::LinearEncoder,
}

impl FrameEncoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Encodes a linear-RGB, row-major frame of `width` x `height` pixels. `UNSPECIFIED` is
    /// encoded as QOI (see [`effective_encoding`]).
    pub fn encode(&mut self, linear: &[Vec3], width: u32, height: u32, encoding: FrameEncoding) -> Result<Vec<u8>, CodecError> {
        check_size(linear, width, height)?;
        match effective_encoding(encoding) {
            FrameEncoding::Qoi => Ok(self.qoi(linear, width as usize, height as usize)),
            FrameEncoding::LinearHalfLz4 => Ok(self.linear.encode(linear, width as usize, height as usize)),
            FrameEncoding::RawRgb8 => {
                let mut out = Vec::new();
                to_srgb8(linear, width, height, &mut out)?;
                Ok(out)
            }
            other => {
                to_srgb8(linear, width, height, &mut self.rgb)?;
                encode_srgb8(&self.rgb, width, height, other)
            }
        }
    }

    fn qoi(&mut self, linear: &[Vec3], w: usize, h: usize) -> Vec<u8> {
        let bands = h.div_ceil(BAND_ROWS);
        self.bands.resize_with(bands, Band::default);
        self.bands.par_iter_mut().enumerate().for_each(|(i, band)| {
            let (y0, y1) = (i * BAND_ROWS, ((i + 1) * BAND_ROWS).min(h));
            // The band continues from the frame's pixel before it.
            let prev = match (y0 * w).checked_sub(1) {
                Some(p) => pack(srgb::encode_rgb(linear[p])),
                None => qoi::START_PIXEL,
            };
            band.row.resize(w, 0);
            let mut enc = qoi::BandEncoder::new(prev, &mut band.qoi);
            for src in linear[y0 * w..y1 * w].chunks_exact(w) {
                srgb::encode_row_rgba(src, &mut band.row);
                enc.push(&band.row);
            }
            band.len = enc.finish();
        });
        let len = qoi::HEADER_LEN + self.bands.iter().map(|b| b.len).sum::<usize>() + qoi::END_MARKER.len();
        let mut out = Vec::with_capacity(len);
        out.extend_from_slice(&qoi::header(w as u32, h as u32));
        for b in &self.bands {
            out.extend_from_slice(&b.qoi[..b.len]);
        }
        out.extend_from_slice(&qoi::END_MARKER);
        out
    }
}

/// A packed QOI pixel of an sRGB colour.
fn pack([r, g, b]: [u8; 3]) -> u32 {
    u32::from_le_bytes([r, g, b, 255])
}

/// Encodes a linear-RGB, row-major frame of `width` x `height` pixels (a one-off
/// [`FrameEncoder`]; a session keeps one instead).
pub fn encode_frame(linear: &[Vec3], width: u32, height: u32, encoding: FrameEncoding) -> Result<Vec<u8>, CodecError> {
    FrameEncoder::new().encode(linear, width, height, encoding)
}

/// Encodes interleaved sRGB8 bytes (`width * height * 3`) with the `image` crate.
pub fn encode_srgb8(rgb: &[u8], width: u32, height: u32, encoding: FrameEncoding) -> Result<Vec<u8>, CodecError> {
    let encoding = effective_encoding(encoding);
    let expected = width as usize * height as usize * 3;
    if rgb.len() != expected || expected == 0 {
        return Err(CodecError::RawLength { got: rgb.len(), expected });
    }
    let enc = name(encoding);
    let wrap = |source| CodecError::Image { encoding: enc, source };
    match encoding {
        FrameEncoding::RawRgb8 => Ok(rgb.to_vec()),
        FrameEncoding::Qoi => {
            let mut out = Vec::with_capacity(rgb.len() / 2);
            QoiEncoder::new(&mut out).write_image(rgb, width, height, ExtendedColorType::Rgb8).map_err(wrap)?;
            Ok(out)
        }
        FrameEncoding::Png => {
            let mut out = Vec::with_capacity(rgb.len() / 2);
            // Fast compression: ~40x quicker than the default level for ~4x the bytes
            // (STACK.md); a frame must leave within the frame budget.
            PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
                .write_image(rgb, width, height, ExtendedColorType::Rgb8)
                .map_err(wrap)?;
            Ok(out)
        }
        FrameEncoding::Jpeg => {
            if width > u16::MAX as u32 || height > u16::MAX as u32 {
                return Err(CodecError::BadSize { width, height, encoding: enc });
            }
            let mut out = Vec::with_capacity(rgb.len() / 8);
            JpegEncoder::new_with_quality(&mut out, JPEG_QUALITY)
                .write_image(rgb, width, height, ExtendedColorType::Rgb8)
                .map_err(wrap)?;
            Ok(out)
        }
        FrameEncoding::LinearHalfLz4 => Err(CodecError::NotFromSrgb { encoding: enc }),
        FrameEncoding::Unspecified => unreachable!("resolved by effective_encoding"),
    }
}

/// Decodes a frame made by [`encode_frame`] back to sRGB8 pixels, checking its size (a
/// linear frame through the sRGB table, as the QOI path would have encoded its half floats).
pub fn decode_frame(bytes: &[u8], encoding: FrameEncoding, width: u32, height: u32) -> Result<Vec<[u8; 3]>, CodecError> {
    let encoding = effective_encoding(encoding);
    if encoding == FrameEncoding::LinearHalfLz4 {
        let f = edgepoint_proto::linear_frame::decode(bytes, width, height)?.to_f32();
        return Ok(f.chunks_exact(3).map(|c| [srgb::encode(c[0]), srgb::encode(c[1]), srgb::encode(c[2])]).collect());
    }
    let enc = name(encoding);
    let n = width as usize * height as usize;
    let flat = match encoding {
        FrameEncoding::RawRgb8 => {
            if bytes.len() != n * 3 {
                return Err(CodecError::RawLength { got: bytes.len(), expected: n * 3 });
            }
            bytes.to_vec()
        }
        _ => {
            let fmt = match encoding {
                FrameEncoding::Qoi => ImageFormat::Qoi,
                FrameEncoding::Png => ImageFormat::Png,
                _ => ImageFormat::Jpeg,
            };
            let img = image::load_from_memory_with_format(bytes, fmt)
                .map_err(|source| CodecError::Image { encoding: enc, source })?
                .into_rgb8();
            if img.width() != width || img.height() != height {
                return Err(CodecError::DecodedSize {
                    encoding: enc,
                    got_w: img.width(),
                    got_h: img.height(),
                    width,
                    height,
                });
            }
            img.into_raw()
        }
    };
    Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image_metrics::{linear_to_srgb8, srgb8_to_linear};

    /// A frame with smooth gradients, a hard edge and noise, so every codec path is used.
    fn test_frame(w: u32, h: u32) -> Vec<Vec3> {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let noise = (state >> 40) as f32 / (1u64 << 24) as f32 * 0.05;
                let edge = if x + 0.3 * y > 0.6 { 0.8 } else { 0.1 };
                Vec3::new(x, y * y, edge + noise)
            })
            .collect()
    }

    fn srgb_of(frame: &[Vec3]) -> Vec<[u8; 3]> {
        frame.iter().map(|&c| linear_to_srgb8(c)).collect()
    }

    #[test]
    fn lossless_encodings_round_trip_exactly() {
        let (w, h) = (37, 23);
        let frame = test_frame(w, h);
        let want = srgb_of(&frame);
        for enc in [FrameEncoding::RawRgb8, FrameEncoding::Qoi, FrameEncoding::Png, FrameEncoding::Unspecified] {
            let bytes = encode_frame(&frame, w, h, enc).unwrap();
            let got = decode_frame(&bytes, enc, w, h).unwrap();
            assert_eq!(got, want, "{enc:?} must round-trip exactly");
        }
        let raw = encode_frame(&frame, w, h, FrameEncoding::RawRgb8).unwrap();
        assert_eq!(raw.len(), (w * h * 3) as usize);
    }

    /// Frames of many shapes (one pixel, one row, one column, heights around the band size)
    /// with flat areas whose runs cross band boundaries: the parallel band encoder's stream
    /// decodes exactly with the `image` crate, and one encoder reused across sizes and
    /// encodings gives the same bytes as a fresh one.
    #[test]
    fn qoi_bands_round_trip_through_the_image_decoder() {
        let mut reused = FrameEncoder::new();
        for (w, h) in [(1, 1), (1, 40), (57, 1), (5, 15), (5, 16), (5, 17), (33, 49), (64, 100), (3, 2 * BAND_ROWS as u32)] {
            let mut frame = test_frame(w, h);
            // Flat rows and a flat block across the band boundaries.
            for (i, c) in frame.iter_mut().enumerate() {
                let (x, y) = (i as u32 % w, i as u32 / w);
                if y % 7 == 3 || (x < w / 2 && (BAND_ROWS as u32 - 2..BAND_ROWS as u32 + 3).contains(&y)) {
                    *c = Vec3::new(0.25, 0.5, 0.75);
                }
            }
            let want = srgb_of(&frame);
            let bytes = encode_frame(&frame, w, h, FrameEncoding::Qoi).unwrap();
            assert_eq!(decode_frame(&bytes, FrameEncoding::Qoi, w, h).unwrap(), want, "{w}x{h}");
            for enc in [FrameEncoding::Png, FrameEncoding::Qoi, FrameEncoding::RawRgb8, FrameEncoding::Qoi] {
                assert_eq!(reused.encode(&frame, w, h, enc).unwrap(), encode_frame(&frame, w, h, enc).unwrap(), "{w}x{h} {enc:?}");
            }
            // The `image` crate's own QOI encoder of the same bytes decodes to the same pixels.
            let mut rgb = Vec::new();
            to_srgb8(&frame, w, h, &mut rgb).unwrap();
            assert_eq!(rgb, want.concat());
            let theirs = encode_srgb8(&rgb, w, h, FrameEncoding::Qoi).unwrap();
            assert_eq!(decode_frame(&theirs, FrameEncoding::Qoi, w, h).unwrap(), want);
        }
    }

    /// The parallel band encoder writes the bytes of the one-thread reference encoder,
    /// from a fresh or a reused encoder, and its frames decode to the half floats of the
    /// linear pixels; sRGB bytes cannot be made into a linear frame.
    #[test]
    fn linear_frames_match_the_reference_encoder_and_round_trip() {
        use edgepoint_proto::linear_frame::{self, LinearFrame};
        let mut reused = FrameEncoder::new();
        for (w, h) in [(1, 1), (5, 17), (64, 100), (33, 2 * BAND_ROWS as u32 + 1)] {
            let frame: Vec<Vec3> = test_frame(w, h).into_iter().map(|c| c * 30.0).collect();
            let want = linear_frame::encode(&frame, w, h);
            for enc in [FrameEncoding::Qoi, FrameEncoding::LinearHalfLz4] {
                let _ = reused.encode(&frame, w, h, enc).unwrap();
            }
            assert_eq!(reused.encode(&frame, w, h, FrameEncoding::LinearHalfLz4).unwrap(), want, "{w}x{h}");
            assert_eq!(encode_frame(&frame, w, h, FrameEncoding::LinearHalfLz4).unwrap(), want);
            assert_eq!(linear_frame::decode(&want, w, h).unwrap(), LinearFrame::from_linear(&frame, w, h));
        }
        assert!(matches!(encode_srgb8(&[0; 3], 1, 1, FrameEncoding::LinearHalfLz4), Err(CodecError::NotFromSrgb { .. })));
        assert!(matches!(decode_frame(b"EPH1", FrameEncoding::LinearHalfLz4, 1, 1), Err(CodecError::Linear(_))));
    }

    #[test]
    fn jpeg_round_trips_closely_and_is_smaller() {
        let (w, h) = (64, 48);
        let frame = test_frame(w, h);
        let want = srgb_of(&frame);
        let bytes = encode_frame(&frame, w, h, FrameEncoding::Jpeg).unwrap();
        assert!(bytes.len() < (w * h * 3) as usize);
        let got = decode_frame(&bytes, FrameEncoding::Jpeg, w, h).unwrap();
        let lin = |p: &[[u8; 3]]| p.iter().map(|&c| srgb8_to_linear(c)).collect::<Vec<_>>();
        let psnr = crate::image_metrics::psnr(&lin(&got), &lin(&want));
        assert!(psnr > 30.0, "JPEG q90 PSNR {psnr} dB");
        let mean_abs: f64 = got
            .iter()
            .zip(&want)
            .flat_map(|(a, b)| (0..3).map(move |k| (a[k] as f64 - b[k] as f64).abs()))
            .sum::<f64>()
            / (want.len() * 3) as f64;
        assert!(mean_abs < 4.0, "mean abs error {mean_abs}");
    }

    #[test]
    fn wrong_sizes_are_errors_not_panics() {
        let frame = test_frame(8, 8);
        assert!(matches!(encode_frame(&frame, 8, 9, FrameEncoding::Qoi), Err(CodecError::SizeMismatch { .. })));
        assert!(encode_frame(&[], 0, 0, FrameEncoding::Png).is_err());
        let bytes = encode_frame(&frame, 8, 8, FrameEncoding::Png).unwrap();
        assert!(matches!(decode_frame(&bytes, FrameEncoding::Png, 4, 16), Err(CodecError::DecodedSize { .. })));
        assert!(decode_frame(&bytes[..10], FrameEncoding::Png, 8, 8).is_err());
        assert!(decode_frame(&[1, 2, 3], FrameEncoding::RawRgb8, 8, 8).is_err());
        assert!(decode_frame(b"garbage", FrameEncoding::Qoi, 8, 8).is_err());
    }
}
