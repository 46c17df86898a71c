//! Base-colour textures: linear RGB texels with bilinear, wrapping lookups.
use glam::{Vec2, Vec3};

/// A base-colour texture: linear RGB texels, row 0 at v = 0 (the loader flips images
/// whose rows run the other way), repeated outside [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// `width * height` linear RGB texels, row-major.
    pub texels: Vec<Vec3>,
}

impl Texture {
    /// Bilinear lookup with wrap-around; black for an empty texture.
    pub fn sample(&self, uv: Vec2) -> Vec3 {
        let (w, h) = (self.width as usize, self.height as usize);
        if w == 0 || h == 0 || self.texels.len() < w * h {
            return Vec3::ZERO;
        }
        let x = uv.x.rem_euclid(1.0) * w as f32 - 0.5;
        let y = uv.y.rem_euclid(1.0) * h as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let wrap = |i: f32, n: usize| (i as i64).rem_euclid(n as i64) as usize;
        let (xa, xb) = (wrap(x0, w), wrap(x0 + 1.0, w));
        let (ya, yb) = (wrap(y0, h), wrap(y0 + 1.0, h));
        let t = |x: usize, y: usize| self.texels[y * w + x];
        let top = t(xa, ya) * (1.0 - fx) + t(xb, ya) * fx;
        let bottom = t(xa, yb) * (1.0 - fx) + t(xb, yb) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}
