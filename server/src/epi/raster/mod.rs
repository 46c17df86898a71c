//! Edge rasterization, paper 000 §4.5: every discontinuity segment is clipped to the near
//! plane, projected, and its crossings with the pixel-boundary lines (the vertical lines
//! `x = X` and horizontal lines `y = Y`) are recorded at 1/8-pixel precision — one bit per
//! eighth of a pixel side, 8-bit masks, 16 bits per pixel since neighbours share sides.
//! With the complex filter on (§5.4) the crossings with the two centre lines of each pixel
//! (`x = X + 1/2`, `y = Y + 1/2`) are recorded as well.
//!
//! Beside the masks, each pixel side keeps where its last recorded crossing lies within its
//! eighth, in 1/256 of the eighth ([`Boundaries::fine`]: 1/2048 of the side, one byte a side,
//! 2 bytes per pixel): classification and reachability use only the eighths (§4.2), the anti-aliasing of
//! simple pixels (§5.3) the exact positions, since on a long, nearly horizontal edge the
//! eighth is the same along a whole run of pixels and the error of its area does not
//! average out.
//!
//! A crossing whose depth (perspective-correct: inverse depth is linear along the projected
//! segment) lies behind the conservative depth buffer ([`super::depth`]) at the nearest
//! pixel corner is dropped: occlusion culling.
//!
//! Work is split into bands of rows; each segment is binned into the bands its projection
//! spans, and each band writes only its own rows, so bands run in parallel without locks.
use super::code::{pixel_mask, BOTTOM, RIGHT, TOP};
use super::depth::ConservativeDepth;
use crate::edges::EdgeSegment;
use edgepoint_scene::camera::CameraFrame;
use rayon::prelude::*;

/// Rows of boundary lines per band.
pub const BAND_ROWS: usize = 16;
/// Segments are clipped to this view depth (as reprojection drops points nearer than it).
pub const NEAR: f64 = 1e-6;

/// The recorded crossings.
pub struct Boundaries {
    pub width: usize,
    pub height: usize,
    /// `(width + 1) * (height + 1)` entries, row-major over grid vertices (x, y): the low byte
    /// holds the crossings of the vertical line `x` within `[y, y + 1)` (the left side of
    /// pixel (x, y)), the high byte those of the horizontal line `y` within `[x, x + 1)`
    /// (its top side). Bit `k` = the k-th eighth along the line's direction.
    pub sides: Vec<u16>,
    /// `width * height` entries when centre lines are recorded (else empty): low byte the
    /// vertical centre line `x + 1/2` within `[y, y + 1)`, high byte the horizontal one
    /// `y + 1/2` within `[x, x + 1)`.
    pub centres: Vec<u16>,
    /// Parallel to `sides`: the low byte where the left side's last recorded crossing lies
    /// within its eighth, the high byte the top side's, in 1/256 of the eighth (the low byte
    /// of [`fine_position`]); meaningful where the side's mask has exactly one bit (the
    /// eighth), as a simple pixel's crossed sides have. Never cleared (written with every
    /// bit). Empty when the masks came from elsewhere (tests): the anti-aliasing then uses
    /// the eighths.
    pub fine: Vec<u16>,
    /// Bit rows (`ceil(width / 64)` words per row): the pixels holding a visible end of a
    /// segment — where an outline may turn (a rectangle's corner), so that the crossings of
    /// a simple pixel need not lie on one line. Empty with `fine`.
    pub ends: Vec<u64>,
}

/// A crossing at `f` ∈ [0, 1) along a side, in 1/2048 of the side: its eighth (paper 000
/// §4.2) is `q >> 8` (the same as `floor(8 f)`: both scalings are exact), the low byte is
/// what [`Boundaries::fine`] keeps, and `(q + 1/2) / 2048` is within 2^-12 of `f`.
#[inline]
pub fn fine_position(f: f64) -> u32 {
    ((f * 2048.0) as u32).min(2047)
}

/// The side position `q` of [`fine_position`] as a fraction of the side.
#[inline]
pub fn fine_fraction(q: u32) -> f32 {
    (q as f32 + 0.5) * (1.0 / 2048.0)
}

impl Boundaries {
    /// Bytes of the masks of a `width` × `height` image, with the centre lines the complex
    /// filter adds ([`crate::epi::Epi::build`] allocates them on its first frame with it),
    /// the crossings' fine positions (2 bytes per grid vertex) and the segment-end bits.
    pub fn bytes_for(width: usize, height: usize) -> usize {
        (2 + 2) * (width + 1) * (height + 1) + 2 * width * height + 8 * height * width.div_ceil(64)
    }

    pub fn new(width: usize, height: usize) -> Self {
        let n = (width + 1) * (height + 1);
        Boundaries { width, height, sides: vec![0; n], centres: Vec::new(), fine: vec![0; n], ends: vec![0; height * width.div_ceil(64)] }
    }

    pub fn bytes(&self) -> usize {
        2 * (self.sides.len() + self.centres.len() + self.fine.len()) + 8 * self.ends.len()
    }

    /// Whether pixel (x, y) holds a visible segment end (false without fine positions).
    #[inline]
    pub fn holds_end(&self, x: usize, y: usize) -> bool {
        self.ends.get(y * self.width.div_ceil(64) + x / 64).is_some_and(|&word| (word >> (x % 64)) & 1 == 1)
    }

    /// Where the crossing of pixel (x, y)'s side (`code::TOP` … `code::LEFT`) lies within its
    /// eighth, in 1/256 of it (the low byte of [`fine_position`]), if the boundaries have
    /// fine positions; meaningful where the side has one crossing.
    #[inline]
    pub fn fine_at(&self, x: usize, y: usize, side: u32) -> Option<u32> {
        let stride = self.width + 1;
        let (vx, vy, high) = match side {
            TOP => (x, y, true),
            RIGHT => (x + 1, y, false),
            BOTTOM => (x, y + 1, true),
            _ => (x, y, false),
        };
        let f = *self.fine.get(vy * stride + vx)?;
        Some(u32::from(if high { f >> 8 } else { f & 0xFF }))
    }

    #[inline]
    fn vertex(&self, x: usize, y: usize) -> u16 {
        self.sides[y * (self.width + 1) + x]
    }

    #[inline]
    pub fn left(&self, x: usize, y: usize) -> u8 {
        self.vertex(x, y) as u8
    }

    #[inline]
    pub fn top(&self, x: usize, y: usize) -> u8 {
        (self.vertex(x, y) >> 8) as u8
    }

    #[inline]
    pub fn right(&self, x: usize, y: usize) -> u8 {
        self.left(x + 1, y)
    }

    #[inline]
    pub fn bottom(&self, x: usize, y: usize) -> u8 {
        self.top(x, y + 1)
    }

    /// Crossing mask of pixel (x, y) for [`super::code::Cell::classify`].
    #[inline]
    pub fn mask(&self, x: usize, y: usize) -> u32 {
        pixel_mask(self.top(x, y), self.right(x, y), self.bottom(x, y), self.left(x, y))
    }

    /// Crossings of pixel (x, y)'s vertical centre line (0 without centre lines).
    #[inline]
    pub fn centre_vertical(&self, x: usize, y: usize) -> u8 {
        self.centres.get(y * self.width + x).map_or(0, |&c| c as u8)
    }

    /// Crossings of pixel (x, y)'s horizontal centre line (0 without centre lines).
    #[inline]
    pub fn centre_horizontal(&self, x: usize, y: usize) -> u8 {
        self.centres.get(y * self.width + x).map_or(0, |&c| (c >> 8) as u8)
    }
}

/// A segment projected to the screen: pixel coordinates and inverse view depth at both ends.
#[derive(Debug, Clone, Copy)]
pub struct ScreenSegment {
    pub x0: f64,
    pub y0: f64,
    pub w0: f64,
    pub x1: f64,
    pub y1: f64,
    pub w1: f64,
}

/// What one rasterization did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RasterCounts {
    /// Segments given.
    pub segments: u32,
    /// Segments with some part in front of the near plane and over the screen.
    pub on_screen: u32,
    /// Crossings recorded (pixel sides and centre lines).
    pub fragments: u32,
    /// Crossings dropped behind the conservative depth.
    pub culled: u32,
}

impl std::ops::AddAssign for RasterCounts {
    fn add_assign(&mut self, o: Self) {
        self.segments += o.segments;
        self.on_screen += o.on_screen;
        self.fragments += o.fragments;
        self.culled += o.culled;
    }
}

/// The camera prepared for projecting segments (the same projection as the Render Cache's
/// points, in f64).
#[derive(Debug, Clone, Copy)]
pub struct SegmentProjector {
    eye: [f64; 3],
    rx: [f64; 3],
    uy: [f64; 3],
    f: [f64; 3],
    cx: f64,
    cy: f64,
}

fn v64(v: glam::Vec3) -> [f64; 3] {
    [v.x as f64, v.y as f64, v.z as f64]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl SegmentProjector {
    /// For an image of `width` x `height` (the frame's own size is ignored).
    pub fn new(cam: &CameraFrame, width: usize, height: usize) -> Self {
        let cx = 0.5 * width as f64;
        let cy = 0.5 * height as f64;
        let tan = cam.tan_half_y as f64;
        let aspect = width as f64 / height.max(1) as f64;
        let s = |v: [f64; 3], k: f64| [v[0] * k, v[1] * k, v[2] * k];
        SegmentProjector { eye: v64(cam.eye), rx: s(v64(cam.right), cx / (tan * aspect)), uy: s(v64(cam.up), cy / tan), f: v64(cam.forward), cx, cy }
    }

    /// `p`'s depth along the view direction.
    pub fn depth(&self, p: glam::Vec3) -> f64 {
        let p = v64(p);
        dot([p[0] - self.eye[0], p[1] - self.eye[1], p[2] - self.eye[2]], self.f)
    }

    /// `p`'s position in pixels (as [`Self::project`] places segment ends), or `None` when
    /// it is not in front of the near plane.
    pub fn pixel(&self, p: glam::Vec3) -> Option<[f64; 2]> {
        let p = v64(p);
        let p = [p[0] - self.eye[0], p[1] - self.eye[1], p[2] - self.eye[2]];
        let z = dot(p, self.f);
        (z >= NEAR).then(|| [self.cx + dot(p, self.rx) / z, self.cy - dot(p, self.uy) / z])
    }

    /// The segment clipped to the near plane and projected, or `None` if it lies wholly
    /// behind it.
    pub fn project(&self, e: &EdgeSegment) -> Option<ScreenSegment> {
        let d = |p: glam::Vec3| {
            let p = v64(p);
            [p[0] - self.eye[0], p[1] - self.eye[1], p[2] - self.eye[2]]
        };
        let (mut a, mut b) = (d(e.a), d(e.b));
        let (za, zb) = (dot(a, self.f), dot(b, self.f));
        if !(za.is_finite() && zb.is_finite()) || (za < NEAR && zb < NEAR) {
            return None;
        }
        let lerp = |p: [f64; 3], q: [f64; 3], t: f64| [p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]), p[2] + t * (q[2] - p[2])];
        if za < NEAR {
            a = lerp(a, b, (NEAR - za) / (zb - za));
        } else if zb < NEAR {
            b = lerp(b, a, (NEAR - zb) / (za - zb));
        }
        let screen = |p: [f64; 3]| {
            let z = dot(p, self.f).max(NEAR);
            (self.cx + dot(p, self.rx) / z, self.cy - dot(p, self.uy) / z, 1.0 / z)
        };
        let ((x0, y0, w0), (x1, y1, w1)) = (screen(a), screen(b));
        Some(ScreenSegment { x0, y0, w0, x1, y1, w1 })
    }
}

/// The rasterizer's reusable buffers.
#[derive(Default)]
pub struct Rasterizer {
    segments: Vec<ScreenSegment>,
    /// Per band: indices into `segments`.
    bins: Vec<Vec<u32>>,
}

impl Rasterizer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Bytes of the per-band bin lists of a `height`-row image (their contents, and the
    /// projected segments, grow with the edges on screen, not with the image).
    pub fn bytes_for(height: usize) -> usize {
        (height + 1).div_ceil(BAND_ROWS) * std::mem::size_of::<Vec<u32>>()
    }

    /// Clears `out` and records the crossings of `edges` seen with `cam`, culled against
    /// `depth`; centre lines too when `out.centres` is allocated (`width * height`).
    pub fn rasterize(&mut self, edges: &[EdgeSegment], cam: &CameraFrame, depth: &ConservativeDepth, out: &mut Boundaries) -> RasterCounts {
        let (w, h) = (out.width, out.height);
        let mut counts = RasterCounts { segments: edges.len() as u32, ..Default::default() };
        out.sides.par_iter_mut().for_each(|s| *s = 0);
        out.centres.par_iter_mut().for_each(|s| *s = 0);
        // (Allocated after masks from elsewhere; never cleared otherwise.)
        out.fine.resize(out.sides.len(), 0);
        let words = w.div_ceil(64);
        out.ends.clear();
        out.ends.resize(h * words, 0);
        if w == 0 || h == 0 {
            return counts;
        }
        let prj = SegmentProjector::new(cam, w, h);
        let (wf, hf) = (w as f64, h as f64);
        self.segments.clear();
        self.segments.par_extend(edges.par_iter().filter_map(|e| {
            let s = prj.project(e)?;
            let on = s.x0.max(s.x1) >= 0.0 && s.x0.min(s.x1) <= wf && s.y0.max(s.y1) >= 0.0 && s.y0.min(s.y1) <= hf;
            on.then_some(s)
        }));
        counts.on_screen = self.segments.len() as u32;
        let bands = (h + 1).div_ceil(BAND_ROWS);
        self.bins.resize_with(bands, Vec::new);
        self.bins.iter_mut().for_each(Vec::clear);
        for (i, s) in self.segments.iter().enumerate() {
            let lo = s.y0.min(s.y1).max(0.0).floor() as usize;
            let hi = (s.y0.max(s.y1).min(hf).floor() as usize).min(h);
            for b in lo / BAND_ROWS..=hi / BAND_ROWS {
                self.bins[b].push(i as u32);
            }
        }
        let with_centres = !out.centres.is_empty();
        let centre_chunks: Vec<&mut [u16]> = if with_centres {
            out.centres.chunks_mut(BAND_ROWS * w).chain(std::iter::repeat_with(|| &mut [][..])).take(bands).collect()
        } else {
            (0..bands).map(|_| &mut [][..]).collect()
        };
        // (The last band holds only boundary row `h` when `h` is a multiple of the band.)
        let end_chunks: Vec<&mut [u64]> = out.ends.chunks_mut(BAND_ROWS * words).chain(std::iter::repeat_with(|| &mut [][..])).take(bands).collect();
        let (segs, bins) = (&self.segments, &self.bins);
        let band_counts = out
            .sides
            .par_chunks_mut(BAND_ROWS * (w + 1))
            .zip(out.fine.par_chunks_mut(BAND_ROWS * (w + 1)))
            .zip(centre_chunks.into_par_iter().zip(end_chunks.into_par_iter()))
            .enumerate()
            .map(|(b, ((sides, fine), (centres, ends)))| {
                let band = Band { y_lo: b * BAND_ROWS, y_hi: (b + 1) * BAND_ROWS, w, h, depth, with_centres };
                let mut c = RasterCounts::default();
                for &i in &bins[b] {
                    band.segment(&segs[i as usize], BandOut { sides, fine, centres, ends }, &mut c);
                }
                c
            })
            .reduce(RasterCounts::default, |mut a, b| {
                a += b;
                a
            });
        counts.fragments = band_counts.fragments;
        counts.culled = band_counts.culled;
        counts
    }

    /// Bytes held (not per pixel: proportional to the edges).
    pub fn bytes(&self) -> usize {
        self.segments.capacity() * std::mem::size_of::<ScreenSegment>() + self.bins.iter().map(|b| b.capacity() * 4).sum::<usize>()
    }
}

/// One band of boundary rows `[y_lo, y_hi)` (the last band also holds row `h`).
struct Band<'a> {
    y_lo: usize,
    y_hi: usize,
    w: usize,
    h: usize,
    depth: &'a ConservativeDepth,
    with_centres: bool,
}

/// A band's rows of [`Boundaries`]' buffers.
struct BandOut<'a> {
    sides: &'a mut [u16],
    fine: &'a mut [u16],
    centres: &'a mut [u16],
    ends: &'a mut [u64],
}

/// Eighth of the unit interval holding `f` in [0, 1).
#[inline]
fn eighth(f: f64) -> u32 {
    ((f * 8.0) as u32).min(7)
}

impl Band<'_> {
    /// Records the crossings of `s` with the lines of this band.
    fn segment(&self, s: &ScreenSegment, out: BandOut, c: &mut RasterCounts) {
        let BandOut { sides, fine, centres, ends } = out;
        let (w, h) = (self.w, self.h);
        let (dx, dy) = (s.x1 - s.x0, s.y1 - s.y0);
        let (ylo, yhi) = (self.y_lo as f64, self.y_hi as f64);
        // Parameter range of the part of the segment within the band's rows.
        let (tlo, thi) = if dy != 0.0 {
            let (ta, tb) = ((ylo - s.y0) / dy, (yhi - s.y0) / dy);
            (ta.min(tb).max(0.0), ta.max(tb).min(1.0))
        } else if s.y0 >= ylo && s.y0 < yhi {
            (0.0, 1.0)
        } else {
            return;
        };
        // (NaN from a degenerate segment fails too.)
        if tlo > thi || tlo.is_nan() || thi.is_nan() {
            return;
        }
        let inv_depth = |t: f64| s.w0 + t * (s.w1 - s.w0);
        let culled = |z_inv: f64, vx: f64, vy: f64, both_x: bool| {
            let (x, y) = (vx.round() as i64, vy.round() as i64);
            let mut d = self.depth.at(x, y);
            if both_x {
                d = d.max(self.depth.at(x + 1, y));
            }
            // Behind the conservative depth: 1/z < 1/d.
            z_inv * (d as f64) < 1.0
        };
        // The segment's ends in this band's pixel rows, unless behind the conservative depth.
        for (t, x, y) in [(0.0, s.x0, s.y0), (1.0, s.x1, s.y1)] {
            if y >= ylo && y < yhi && y >= 0.0 && y < h as f64 && x >= 0.0 && x < w as f64 && !culled(inv_depth(t), x, y, false) {
                let (px, row) = (x as usize, y as usize - self.y_lo);
                ends[row * w.div_ceil(64) + px / 64] |= 1 << (px % 64);
            }
        }
        // The x range of the band's part, widened by rounding: ownership of a crossing is
        // decided by its own y below, computed the same way in every band.
        let (xa, xb) = (s.x0 + tlo * dx, s.x0 + thi * dx);
        let slack = 1e-9 * (1.0 + xa.abs().max(xb.abs()));
        let (xmin, xmax) = (xa.min(xb) - slack, xa.max(xb) + slack);
        if dx != 0.0 {
            // Vertical lines x = X (and centre lines x = X + 1/2, whose crossings are culled
            // against the depth on both sides).
            for (offset, last) in [(0.0, w), (0.5, w - 1)] {
                let centre = offset > 0.0;
                if centre && !self.with_centres {
                    continue;
                }
                let first = (xmin - offset).ceil().max(0.0) as i64;
                let end = (xmax - offset).floor().min(last as f64) as i64;
                for xl in first..=end {
                    let t = (xl as f64 + offset - s.x0) / dx;
                    let y = s.y0 + t * dy;
                    if !(y >= ylo && y < yhi && y < h as f64 && y >= 0.0) {
                        continue;
                    }
                    if culled(inv_depth(t), xl as f64, y, centre) {
                        c.culled += 1;
                        continue;
                    }
                    let yy = y.floor();
                    let row = yy as usize - self.y_lo;
                    if centre {
                        centres[row * w + xl as usize] |= 1u16 << eighth(y - yy);
                    } else {
                        let (i, q) = (row * (w + 1) + xl as usize, fine_position(y - yy));
                        sides[i] |= 1u16 << (q >> 8);
                        fine[i] = (fine[i] & 0xFF00) | (q & 0xFF) as u16;
                    }
                    c.fragments += 1;
                }
            }
        }
        if dy != 0.0 {
            // Horizontal lines y = Y (and centre lines y = Y + 1/2).
            // Lines from the whole segment's range, restricted to the band's rows.
            let (ymin, ymax) = (s.y0.min(s.y1), s.y0.max(s.y1));
            for (offset, last) in [(0.0, h), (0.5, h - 1)] {
                if offset > 0.0 && !self.with_centres {
                    continue;
                }
                let first = (ymin - offset).ceil().max(self.y_lo as f64) as i64;
                let end = ((ymax - offset).floor().min(last as f64) as i64).min(self.y_hi as i64 - 1);
                for yl in first..=end {
                    let t = (yl as f64 + offset - s.y0) / dy;
                    let x = s.x0 + t * dx;
                    if !(x >= 0.0 && x < w as f64) {
                        continue;
                    }
                    let xx = x.floor();
                    if offset == 0.0 {
                        if culled(inv_depth(t), x, yl as f64, false) {
                            c.culled += 1;
                            continue;
                        }
                        let (i, q) = ((yl as usize - self.y_lo) * (w + 1) + xx as usize, fine_position(x - xx));
                        sides[i] |= 1u16 << (8 + (q >> 8));
                        fine[i] = (fine[i] & 0x00FF) | ((q & 0xFF) as u16) << 8;
                    } else {
                        if culled(inv_depth(t), x, yl as f64 + 0.5, false) {
                            c.culled += 1;
                            continue;
                        }
                        centres[(yl as usize - self.y_lo) * w + xx as usize] |= 1u16 << (8 + eighth(x - xx));
                    }
                    c.fragments += 1;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
