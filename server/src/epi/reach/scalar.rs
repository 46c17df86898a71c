//! The paper's formulation of §5.2, pixel by pixel: 4-bit masks from the neighbour table,
//! chained with the chaining table along the monotone paths, ORed, and the 12 offsets
//! before the centre taken from the pixels before it (symmetry). One `u32` (24 bits used)
//! per pixel. Kept as a second implementation: the tests check the bit-sliced
//! [`super::Reach`] against it, and the `epi` benchmark times both.
use super::class4;
use crate::epi::code::EpiPixel;
use crate::epi::reach::mask_bit;
use crate::epi::tables::{tables, Tables, DIR_DOWN, DIR_LEFT, DIR_RIGHT};
use rayon::prelude::*;

/// Per-pixel 24-bit primary-to-primary masks (bit [`mask_bit`]`(k)` for window index `k`).
pub struct ScalarReach {
    pub width: usize,
    pub height: usize,
    pub masks: Vec<u32>,
}

/// Window index of offset (dx, dy).
const fn k(dx: i32, dy: i32) -> usize {
    ((dy + 2) * 5 + dx + 2) as usize
}

impl ScalarReach {
    pub fn new(width: usize, height: usize) -> Self {
        ScalarReach { width, height, masks: vec![0; width * height] }
    }

    pub fn bytes(&self) -> usize {
        self.masks.len() * 4
    }

    /// Computes every pixel's mask: the 12 offsets after the centre by table chaining (in
    /// parallel over rows), then the 12 before it copied from the pixels they point to.
    pub fn compute(&mut self, pixels: &[EpiPixel]) {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return;
        }
        let t = tables();
        self.masks.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, m) in row.iter_mut().enumerate() {
                *m = lower_half(t, pixels, w, h, x as i64, y as i64);
            }
        });
        // Symmetry: the bit for offset o of pixel c is the bit for -o of pixel c + o, which
        // lies on an earlier scanline (or earlier on this one).
        let lower = &self.masks;
        let mut full = vec![0u32; w * h];
        full.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, out) in row.iter_mut().enumerate() {
                let mut m = lower[y * w + x];
                for kk in 0..12 {
                    let (dx, dy) = super::offset(kk);
                    let (px, py) = (x as i64 + dx as i64, y as i64 + dy as i64);
                    if px >= 0 && py >= 0 && px < w as i64 {
                        m |= ((lower[py as usize * w + px as usize] >> mask_bit(24 - kk)) & 1) << mask_bit(kk);
                    }
                }
                *out = m;
            }
        });
        self.masks = full;
    }

    pub fn mask24(&self, x: usize, y: usize) -> u32 {
        self.masks[y * self.width + x]
    }
}

/// Bits of the 12 offsets after the centre of pixel (x, y).
fn lower_half(t: &Tables, pixels: &[EpiPixel], w: usize, h: usize, x: i64, y: i64) -> u32 {
    // 4-bit code of the pixel at offset (dx, dy); outside the image: complex (blocks).
    let c = |dx: i32, dy: i32| -> u8 {
        let (px, py) = (x + dx as i64, y + dy as i64);
        if px < 0 || py < 0 || px >= w as i64 || py >= h as i64 {
            crate::epi::tables::CLASS_COMPLEX
        } else {
            class4(t, pixels[py as usize * w + px as usize])
        }
    };
    let right = |ax, ay| t.neighbour(DIR_RIGHT, c(ax, ay), c(ax + 1, ay));
    let left = |ax, ay| t.neighbour(DIR_LEFT, c(ax, ay), c(ax - 1, ay));
    let down = |ax, ay| t.neighbour(DIR_DOWN, c(ax, ay), c(ax, ay + 1));
    let ch = |a: u8, b: u8| t.chain(a, b);
    let m10 = right(0, 0);
    let mm10 = left(0, 0);
    let m20 = ch(m10, right(1, 0));
    let mm20 = ch(mm10, left(-1, 0));
    let m01 = down(0, 0);
    let m11 = ch(m10, down(1, 0)) | ch(m01, right(0, 1));
    let mm11 = ch(mm10, down(-1, 0)) | ch(m01, left(0, 1));
    let m21 = ch(m20, down(2, 0)) | ch(m11, right(1, 1));
    let mm21 = ch(mm20, down(-2, 0)) | ch(mm11, left(-1, 1));
    let m02 = ch(m01, down(0, 1));
    let m12 = ch(m11, down(1, 1)) | ch(m02, right(0, 2));
    let mm12 = ch(mm11, down(-1, 1)) | ch(m02, left(0, 2));
    let m22 = ch(m21, down(2, 1)) | ch(m12, right(1, 2));
    let mm22 = ch(mm21, down(-2, 1)) | ch(mm12, left(-1, 2));
    let pp = |m: u8| u32::from(m & 1);
    [
        (k(1, 0), m10),
        (k(2, 0), m20),
        (k(-2, 1), mm21),
        (k(-1, 1), mm11),
        (k(0, 1), m01),
        (k(1, 1), m11),
        (k(2, 1), m21),
        (k(-2, 2), mm22),
        (k(-1, 2), mm12),
        (k(0, 2), m02),
        (k(1, 2), m12),
        (k(2, 2), m22),
    ]
    .into_iter()
    .fold(0, |acc, (kk, m)| acc | pp(m) << mask_bit(kk))
}
