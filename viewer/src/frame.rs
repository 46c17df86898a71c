//! Frame bytes to pixels: the wire encodings of `Frame.data` (raw sRGB8, QOI, PNG, JPEG;
//! DESIGN.md "One frame in the renderer", step 12) decoded into an RGB image, and linear
//! half-float frames decoded to their radiance and tone-mapped for display.
use crate::tonemap::{Look, ToneMapper};
use anyhow::{bail, Context, Result};
use edgepoint_proto::linear_frame::{self, LinearFrame};
use edgepoint_proto::{self as pb, FrameEncoding};
use image::{ImageFormat, RgbImage};
use std::sync::{Arc, OnceLock};

/// Short lower-case name of a wire encoding (`raw`, `qoi`, `png`, `jpeg`).
pub fn encoding_name(encoding: i32) -> &'static str {
    match FrameEncoding::try_from(encoding) {
        Ok(FrameEncoding::RawRgb8) => "raw",
        Ok(FrameEncoding::Qoi) => "qoi",
        Ok(FrameEncoding::Png) => "png",
        Ok(FrameEncoding::Jpeg) => "jpeg",
        Ok(FrameEncoding::LinearHalfLz4) => "linear-half-lz4",
        Ok(FrameEncoding::Unspecified) => "unspecified",
        Err(_) => "unknown",
    }
}

/// A decoded frame: what to show or write as PNG, and the radiance when the frame is linear.
pub struct Decoded {
    pub image: RgbImage,
    pub linear: Option<Arc<LinearFrame>>,
}

/// Decodes a frame; a linear frame is tone-mapped with `tone` (an sRGB frame is shown as it
/// is: exposure and tone mapping need the radiance).
pub fn decode_with(f: &pb::Frame, tone: &ToneMapper) -> Result<Decoded> {
    if f.encoding == FrameEncoding::LinearHalfLz4 as i32 {
        let lin = linear_frame::decode(&f.data, f.width, f.height).with_context(|| describe(f))?;
        return Ok(Decoded { image: tone.map(&lin), linear: Some(Arc::new(lin)) });
    }
    Ok(Decoded { image: decode_frame(f)?, linear: None })
}

fn describe(f: &pb::Frame) -> String {
    format!("frame {} ({}, {}x{}, {} bytes)", f.sequence, encoding_name(f.encoding), f.width, f.height, f.data.len())
}

/// Decodes a frame into 8-bit sRGB pixels and checks that the image has the size the
/// frame claims (a linear frame with exposure 0 and clipping: the renderer's own sRGB of
/// its half floats). Errors name the frame's sequence number and encoding.
pub fn decode_frame(f: &pb::Frame) -> Result<RgbImage> {
    let (w, h) = (f.width, f.height);
    let what = || describe(f);
    if f.encoding == FrameEncoding::LinearHalfLz4 as i32 {
        static IDENTITY: OnceLock<ToneMapper> = OnceLock::new();
        return Ok(decode_with(f, IDENTITY.get_or_init(|| ToneMapper::new(Look::default())))?.image);
    }
    let img = match FrameEncoding::try_from(f.encoding) {
        Ok(FrameEncoding::RawRgb8) => {
            let want = w as u64 * h as u64 * 3;
            if f.data.len() as u64 != want {
                bail!("{}: raw RGB8 data should be {want} bytes (width*height*3)", what());
            }
            RgbImage::from_raw(w, h, f.data.clone()).with_context(what)?
        }
        Ok(enc) => {
            let format = match enc {
                FrameEncoding::Qoi => ImageFormat::Qoi,
                FrameEncoding::Png => ImageFormat::Png,
                FrameEncoding::Jpeg => ImageFormat::Jpeg,
                // "Unspecified" only makes sense in a request; trust the bytes' signature.
                _ => image::guess_format(&f.data).with_context(|| format!("{}: unrecognised image data", what()))?,
            };
            image::load_from_memory_with_format(&f.data, format)
                .with_context(|| format!("{}: cannot decode", what()))?
                .to_rgb8()
        }
        Err(_) => bail!("{}: unknown encoding value {}", what(), f.encoding),
    };
    if img.dimensions() != (w, h) {
        bail!("{}: the image inside is {}x{}", what(), img.width(), img.height());
    }
    Ok(img)
}

/// Packs an RGB image into 0RGB `u32` pixels (the window framebuffer layout), reusing `out`.
pub fn to_0rgb(img: &RgbImage, out: &mut Vec<u32>) {
    out.clear();
    out.extend(img.pixels().map(|p| ((p[0] as u32) << 16) | ((p[1] as u32) << 8) | p[2] as u32));
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::ImageEncoder;

    fn test_image(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 7) as u8, (y * 13) as u8, ((x + y) * 3) as u8]))
    }

    fn frame(img: &RgbImage, enc: FrameEncoding, data: Vec<u8>) -> pb::Frame {
        pb::Frame { sequence: 3, width: img.width(), height: img.height(), encoding: enc as i32, data, ..Default::default() }
    }

    fn encode(img: &RgbImage, format: ImageFormat) -> Vec<u8> {
        let mut buf = std::io::Cursor::new(Vec::new());
        img.write_to(&mut buf, format).unwrap();
        buf.into_inner()
    }

    #[test]
    fn lossless_encodings_decode_exactly() {
        let img = test_image(37, 21);
        for (enc, data) in [
            (FrameEncoding::RawRgb8, img.as_raw().clone()),
            (FrameEncoding::Qoi, encode(&img, ImageFormat::Qoi)),
            (FrameEncoding::Png, encode(&img, ImageFormat::Png)),
            (FrameEncoding::Unspecified, encode(&img, ImageFormat::Qoi)),
        ] {
            assert_eq!(decode_frame(&frame(&img, enc, data)).unwrap(), img, "{enc:?}");
        }
    }

    #[test]
    fn jpeg_decodes_close() {
        let img = RgbImage::from_pixel(32, 16, image::Rgb([200, 100, 50]));
        let mut data = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut data, 95)
            .write_image(img.as_raw(), 32, 16, image::ExtendedColorType::Rgb8)
            .unwrap();
        let got = decode_frame(&frame(&img, FrameEncoding::Jpeg, data)).unwrap();
        for (a, b) in got.pixels().zip(img.pixels()) {
            for c in 0..3 {
                assert!((a[c] as i32 - b[c] as i32).abs() <= 4, "{a:?} vs {b:?}");
            }
        }
    }

    #[test]
    fn bad_frames_are_errors_not_panics() {
        let img = test_image(8, 8);
        let short = frame(&img, FrameEncoding::RawRgb8, vec![0; 10]);
        assert!(format!("{:#}", decode_frame(&short).unwrap_err()).contains("192 bytes"));
        let garbage = frame(&img, FrameEncoding::Qoi, vec![1, 2, 3, 4, 5]);
        assert!(format!("{:#}", decode_frame(&garbage).unwrap_err()).contains("frame 3 (qoi"));
        let mut wrong_size = frame(&img, FrameEncoding::Png, encode(&img, ImageFormat::Png));
        wrong_size.width = 9;
        assert!(format!("{:#}", decode_frame(&wrong_size).unwrap_err()).contains("inside is 8x8"));
        let unknown = pb::Frame { encoding: 99, ..frame(&img, FrameEncoding::Png, vec![]) };
        assert!(decode_frame(&unknown).is_err());
    }

    #[test]
    fn packs_0rgb() {
        let img = RgbImage::from_pixel(2, 1, image::Rgb([0x12, 0x34, 0x56]));
        let mut out = vec![7; 5];
        to_0rgb(&img, &mut out);
        assert_eq!(out, vec![0x123456, 0x123456]);
    }
}
