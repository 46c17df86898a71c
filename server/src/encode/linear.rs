//! The linear frame encoding (`FRAME_ENCODING_LINEAR_HALF_LZ4`, layout in
//! `edgepoint_proto::linear_frame`): bands of rows converted to half floats and compressed
//! in parallel, next to the sRGB QOI path and sharing nothing with it, so the window's QOI
//! frames cost what they did.
use edgepoint_proto::linear_frame::{self, BandScratch, BAND_ROWS};
use glam::Vec3;
use rayon::prelude::*;

/// One band's buffers, kept from frame to frame.
#[derive(Default)]
struct Band {
    scratch: BandScratch,
    lz4: Vec<u8>,
}

/// Encodes linear frames, keeping its working buffers from frame to frame.
#[derive(Default)]
pub struct LinearEncoder {
    bands: Vec<Band>,
}

impl LinearEncoder {
    /// Encodes a row-major frame of `w` x `h` pixels (`linear.len() == w * h`).
    pub fn encode(&mut self, linear: &[Vec3], w: usize, h: usize) -> Vec<u8> {
        self.bands.resize_with(h.div_ceil(BAND_ROWS), Band::default);
        self.bands.par_iter_mut().zip(linear.par_chunks(w * BAND_ROWS)).for_each(|(band, rows)| {
            linear_frame::encode_band(rows, w, &mut band.scratch, &mut band.lz4);
        });
        let lens: Vec<usize> = self.bands.iter().map(|b| b.lz4.len()).collect();
        let mut out = linear_frame::header(w as u32, h as u32, BAND_ROWS, &lens);
        out.reserve(lens.iter().sum());
        for b in &self.bands {
            out.extend_from_slice(&b.lz4);
        }
        out
    }
}
