//! Diagnostic overlays drawn over a reconstructed frame (paper 000 Figures 7 and 10 show
//! the EPI this way):
//! - [`Overlay::Edges`]: pixels crossed by rasterized (unculled) edges, simple ones yellow,
//!   complex ones orange, over the frame;
//! - [`Overlay::Classes`]: pixel classes as in Figure 7 — simple purple, complex green —
//!   over the darkened frame;
//! - [`Overlay::Samples`]: the pixels holding a reprojected sample — white when usable by
//!   edge-respecting interpolation, red when edge-ambiguous, orange in complex pixels —
//!   over the darkened frame.
use super::code::EpiPixel;
use super::Flags;
use glam::Vec3;
use rayon::prelude::*;

/// Which overlay to draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Overlay {
    #[default]
    None,
    Edges,
    Classes,
    Samples,
}

impl Overlay {
    pub const ALL: [Overlay; 4] = [Overlay::None, Overlay::Edges, Overlay::Classes, Overlay::Samples];

    pub fn name(self) -> &'static str {
        match self {
            Overlay::None => "none",
            Overlay::Edges => "edges",
            Overlay::Classes => "classes",
            Overlay::Samples => "samples",
        }
    }
}

pub const SIMPLE_PURPLE: Vec3 = Vec3::new(0.55, 0.1, 0.8);
pub const COMPLEX_GREEN: Vec3 = Vec3::new(0.1, 0.85, 0.2);
pub const EDGE_YELLOW: Vec3 = Vec3::new(1.0, 0.9, 0.1);
pub const EDGE_ORANGE: Vec3 = Vec3::new(1.0, 0.45, 0.0);
pub const SAMPLE_USABLE: Vec3 = Vec3::ONE;
pub const SAMPLE_AMBIGUOUS: Vec3 = Vec3::new(1.0, 0.1, 0.1);
/// Factor applied to the frame under the class and sample overlays.
pub const DIM: f32 = 0.3;

/// Draws `overlay` over `image` (row-major, `flags.width` wide).
pub fn draw(overlay: Overlay, pixels: &[EpiPixel], flags: &Flags, image: &mut [Vec3]) {
    let w = flags.width;
    if overlay == Overlay::None || w == 0 {
        return;
    }
    image.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, c) in row.iter_mut().enumerate() {
            let p = pixels[y * w + x];
            *c = match overlay {
                Overlay::None => *c,
                Overlay::Edges => {
                    if p.is_simple() {
                        EDGE_YELLOW
                    } else if p.is_complex() {
                        EDGE_ORANGE
                    } else {
                        *c
                    }
                }
                Overlay::Classes => {
                    if p.is_simple() {
                        SIMPLE_PURPLE
                    } else if p.is_complex() {
                        COMPLEX_GREEN
                    } else {
                        *c * DIM
                    }
                }
                Overlay::Samples => {
                    if !flags.get(x, y, Flags::HAS) {
                        *c * DIM
                    } else if p.usable() {
                        SAMPLE_USABLE
                    } else if p.is_complex() {
                        EDGE_ORANGE
                    } else {
                        SAMPLE_AMBIGUOUS
                    }
                }
            };
        }
    });
}
