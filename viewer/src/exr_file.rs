//! OpenEXR files of linear RGB (the `exr` crate): never tone-mapped, never clipped.
//!
//! Viewer frames are written as RGB **half**: they arrive as half floats, so a half file
//! holds every bit of the frame at half the size of float. Converged references (the
//! bench) are written as RGB **float**: they are f32 averages of many samples used as
//! ground truth, so no bit is dropped. Compression is ZIP in blocks of 16 scanlines
//! (lossless; chosen by `edgepoint-bench encode`, which measures the write time and size of
//! each lossless method on a real frame).
use anyhow::{bail, Context, Result};
use edgepoint_proto::linear_frame::LinearFrame;
pub use exr::compression::Compression;
use exr::prelude::*;
use half::f16;
use std::path::Path;

/// The compression of the files written here.
pub const COMPRESSION: Compression = Compression::ZIP16;

fn encoding(compression: Compression) -> Encoding {
    Encoding { compression, blocks: Blocks::ScanLines, line_order: LineOrder::Increasing }
}

/// Writes a linear frame as RGB half floats.
pub fn write_half(path: &Path, frame: &LinearFrame) -> Result<()> {
    write_half_with(path, frame, COMPRESSION)
}

/// [`write_half`] with another lossless compression (the bench compares them).
pub fn write_half_with(path: &Path, frame: &LinearFrame, compression: Compression) -> Result<()> {
    let w = frame.width as usize;
    let px = frame.rgb.as_slice();
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let i = (y * w + x) * 3;
        (f16::from_bits(px[i]), f16::from_bits(px[i + 1]), f16::from_bits(px[i + 2]))
    });
    Image::from_encoded_channels((w, frame.height as usize), encoding(compression), channels)
        .write()
        .to_file(path)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Writes linear pixels (row-major, `width * height`) as RGB floats.
pub fn write_f32(path: &Path, width: u32, height: u32, pixels: &[glam::Vec3]) -> Result<()> {
    let w = width as usize;
    if pixels.len() != w * height as usize {
        bail!("{}: {} pixels for a {width}x{height} image", path.display(), pixels.len());
    }
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let p = pixels[y * w + x];
        (p.x, p.y, p.z)
    });
    Image::from_encoded_channels((w, height as usize), encoding(COMPRESSION), channels)
        .write()
        .to_file(path)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Reads the R, G, B channels of an EXR file's first layer as f32 (row-major, interleaved):
/// `(width, height, values)`.
pub fn read_rgb(path: &Path) -> Result<(u32, u32, Vec<f32>)> {
    let img = read_first_rgba_layer_from_file(
        path,
        |size: Vec2<usize>, _: &RgbaChannels| (size.0, vec![0f32; size.0 * size.1 * 3]),
        |(w, px): &mut (usize, Vec<f32>), Vec2(x, y): Vec2<usize>, (r, g, b, _a): (f32, f32, f32, f32)| {
            let i = (y * *w + x) * 3;
            px[i..i + 3].copy_from_slice(&[r, g, b]);
        },
    )
    .with_context(|| format!("cannot read {}", path.display()))?;
    let size = img.layer_data.size;
    Ok((size.0 as u32, size.1 as u32, img.layer_data.channel_data.pixels.1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn half_and_float_files_read_back_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (19u32, 7u32);
        let px: Vec<Vec3> = (0..w * h).map(|i| Vec3::new(i as f32 * 0.37, 1e-5 * i as f32, 300.0 - i as f32)).collect();
        let frame = LinearFrame::from_linear(&px, w, h);
        let path = dir.path().join("half.exr");
        write_half(&path, &frame).unwrap();
        let (rw, rh, got) = read_rgb(&path).unwrap();
        assert_eq!((rw, rh), (w, h));
        assert_eq!(got, frame.to_f32(), "every half float comes back");
        let path = dir.path().join("float.exr");
        write_f32(&path, w, h, &px).unwrap();
        let (_, _, got) = read_rgb(&path).unwrap();
        assert_eq!(got, px.iter().flat_map(|p| p.to_array()).collect::<Vec<_>>(), "f32 exactly, values past 1 kept");
        assert!(write_f32(&path, w, h + 1, &px).is_err());
        assert!(read_rgb(&dir.path().join("missing.exr")).is_err());
    }
}
