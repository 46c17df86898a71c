//! Paper 000 §4.1–4.4: pixel classification and the compact edge and sample encodings.
//!
//! A cell (a pixel, or a quarter pixel for the complex filter of §5.4) has four sides, each
//! cut into `S` boundary segments (8 for pixels: "each side is divided into 8 segments");
//! edge rasterization records which segments an edge crosses. Counting the crossings
//! classifies the cell (§4.5 "Edge reconstruction"):
//! - no crossing: **empty**;
//! - exactly two, on different sides: **simple**, approximated by one edge between the two
//!   segment centres, encoded in 2 × (2 + log2 S) bits — 10 bits for a pixel (5 + 5 on the
//!   32 boundary segments, §4.2);
//! - anything else: **complex**.
//!
//! An edge code is `a << (2 + log2 S) | b` with `a < b` the two perimeter indices. Two codes
//! with both ends on the same side (which a simple edge never has) stand for empty
//! ([`EMPTY`] = ends 0 and 0) and complex ([`COMPLEX`] = ends 0 and 1), so the class needs
//! no extra bits.
//!
//! A perimeter index `p` is `side * S + pos`: sides [`TOP`], [`RIGHT`], [`BOTTOM`], [`LEFT`],
//! and `pos` counts along the side's image axis (x for top and bottom, y for left and
//! right), so two neighbouring cells name a crossing of their shared side by the same
//! `pos` — the property that lets neighbours share the boundary masks (§4.5).
//!
//! Samples are placed in one of `R × R` interior regions (4 × 4 for pixels, §4.3: 4 bits).
//!
//! [`EpiPixel`] packs one pixel's edge code, its sample's region and two flags into 16 bits.

/// Side indices, in perimeter order.
pub const TOP: u32 = 0;
pub const RIGHT: u32 = 1;
pub const BOTTOM: u32 = 2;
pub const LEFT: u32 = 3;

/// Code of an empty cell (both ends at perimeter index 0: disallowed for an edge).
pub const EMPTY: u16 = 0;
/// Code of a complex cell (ends 0 and 1, both on the top side: disallowed for an edge).
pub const COMPLEX: u16 = 1;

/// Geometry of a cell in its own unit square `[0, 1]²` (image orientation: x right, y down).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cell {
    /// Boundary segments per side (a power of two).
    pub segments: u32,
    /// Sample regions per axis.
    pub regions: u32,
}

/// A pixel: 8 segments per side (1/8-pixel precision), 4 × 4 sample regions.
pub const PIXEL: Cell = Cell { segments: 8, regions: 4 };
/// A quarter pixel of the complex filter: its half-pixel sides keep the 1/8-pixel precision
/// (4 segments each), and it holds 2 × 2 of its pixel's sample regions.
pub const SUBPIXEL: Cell = Cell { segments: 4, regions: 2 };

impl Cell {
    /// Bits of `pos`.
    pub const fn pos_bits(self) -> u32 {
        self.segments.trailing_zeros()
    }

    /// Bits of one end (side + pos): 5 for a pixel.
    pub const fn end_bits(self) -> u32 {
        self.pos_bits() + 2
    }

    /// Number of edge codes (1024 for a pixel).
    pub const fn codes(self) -> usize {
        1 << (2 * self.end_bits())
    }

    /// Number of boundary segments around the cell (32 for a pixel).
    pub const fn perimeter(self) -> u32 {
        4 * self.segments
    }

    /// Number of sample regions (16 for a pixel).
    pub const fn region_count(self) -> usize {
        (self.regions * self.regions) as usize
    }

    /// The code of the edge between perimeter indices `a` and `b` (any order).
    #[inline]
    pub fn encode(self, a: u32, b: u32) -> u16 {
        let (a, b) = if a < b { (a, b) } else { (b, a) };
        ((a << self.end_bits()) | b) as u16
    }

    /// The two perimeter indices of a code.
    #[inline]
    pub fn ends(self, code: u16) -> (u32, u32) {
        let code = code as u32;
        (code >> self.end_bits(), code & ((1 << self.end_bits()) - 1))
    }

    /// Whether `code` is a simple edge (ends on two different sides, in order).
    #[inline]
    pub fn is_simple(self, code: u16) -> bool {
        let (a, b) = self.ends(code);
        a < b && b < self.perimeter() && a / self.segments != b / self.segments
    }

    /// Classifies a cell from its crossing mask: bit `p` set when perimeter segment `p` is
    /// crossed (side-major: top bits first, then right, bottom, left). Returns [`EMPTY`],
    /// [`COMPLEX`] or a simple edge code.
    #[inline]
    pub fn classify(self, m: u32) -> u16 {
        if m == 0 {
            return EMPTY;
        }
        let a = m.trailing_zeros();
        let rest = m & (m - 1);
        if rest == 0 || rest & (rest - 1) != 0 {
            return COMPLEX;
        }
        let b = rest.trailing_zeros();
        if a >> self.pos_bits() == b >> self.pos_bits() {
            COMPLEX
        } else {
            self.encode(a, b)
        }
    }

    /// Centre of perimeter segment `p` in cell coordinates: where the approximated edge
    /// ends.
    pub fn boundary_point(self, p: u32) -> [f64; 2] {
        let [s, e] = self.segment(p);
        [(s[0] + e[0]) * 0.5, (s[1] + e[1]) * 0.5]
    }

    /// The two ends of perimeter segment `p` in cell coordinates.
    pub fn segment(self, p: u32) -> [[f64; 2]; 2] {
        let n = self.segments as f64;
        let (side, pos) = (p / self.segments, (p % self.segments) as f64);
        let (t0, t1) = (pos / n, (pos + 1.0) / n);
        match side {
            TOP => [[t0, 0.0], [t1, 0.0]],
            RIGHT => [[1.0, t0], [1.0, t1]],
            BOTTOM => [[t0, 1.0], [t1, 1.0]],
            _ => [[0.0, t0], [0.0, t1]],
        }
    }

    /// Region index of a position `(u, v)` in `[0, 1)²` of the cell: `rx + R * ry` (values
    /// outside are clamped, NaN counts as 0). `R` is a power of two: `1 + t` lies in [1, 2),
    /// where the top mantissa bits of an `f32` are `floor(t * R)` — no float-to-int
    /// conversion, which costs more than the rest of a pixel's classification.
    #[inline]
    // `max` then `min` rather than `clamp`: NaN must become 0, and `clamp` keeps NaN.
    #[allow(clippy::manual_clamp)]
    pub fn region_of(self, u: f32, v: f32) -> u32 {
        let bits = self.regions.trailing_zeros();
        let q = |t: f32| ((t.max(0.0).min(0.999_999) + 1.0).to_bits() >> (23 - bits)) & (self.regions - 1);
        q(u) + self.regions * q(v)
    }

    /// The square of region `r` in cell coordinates: (min corner, max corner).
    pub fn region_square(self, r: u32) -> ([f64; 2], [f64; 2]) {
        let n = self.regions as f64;
        let (rx, ry) = ((r % self.regions) as f64, (r / self.regions) as f64);
        ([rx / n, ry / n], [(rx + 1.0) / n, (ry + 1.0) / n])
    }
}

/// Crossing mask of a pixel from its four side masks (8 bits each), side-major.
#[inline]
pub fn pixel_mask(top: u8, right: u8, bottom: u8, left: u8) -> u32 {
    u32::from(top) | u32::from(right) << 8 | u32::from(bottom) << 16 | u32::from(left) << 24
}

/// One pixel of the edge-and-point image in 16 bits (§4.4): the 10-bit edge code, the
/// 4-bit region of the pixel's sample, whether that sample can be used by edge-respecting
/// interpolation (present, and not edge-ambiguous nor in a complex pixel), and which side of
/// the edge is the primary region (§5.1).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[repr(transparent)]
pub struct EpiPixel(pub u16);

impl EpiPixel {
    const REGION_SHIFT: u32 = 10;
    const USABLE: u16 = 1 << 14;
    const PRIMARY_B: u16 = 1 << 15;

    #[inline]
    pub fn new(code: u16, region: u32, usable: bool, primary_b: bool) -> Self {
        EpiPixel(
            (code & 0x3FF)
                | ((region as u16 & 0xF) << Self::REGION_SHIFT)
                | if usable { Self::USABLE } else { 0 }
                | if primary_b { Self::PRIMARY_B } else { 0 },
        )
    }

    /// The 10-bit edge code ([`EMPTY`], [`COMPLEX`] or a simple edge of [`PIXEL`]).
    #[inline]
    pub fn code(self) -> u16 {
        self.0 & 0x3FF
    }

    /// Region (0..16) of the pixel's sample; 0 without a sample.
    #[inline]
    pub fn region(self) -> u32 {
        u32::from((self.0 >> Self::REGION_SHIFT) & 0xF)
    }

    #[inline]
    pub fn usable(self) -> bool {
        self.0 & Self::USABLE != 0
    }

    /// Whether side B of the edge is the primary region (side A otherwise, and always for
    /// empty and complex pixels).
    #[inline]
    pub fn primary_b(self) -> bool {
        self.0 & Self::PRIMARY_B != 0
    }

    #[inline]
    pub fn is_empty(self) -> bool {
        self.code() == EMPTY
    }

    #[inline]
    pub fn is_complex(self) -> bool {
        self.code() == COMPLEX
    }

    #[inline]
    pub fn is_simple(self) -> bool {
        self.code() > COMPLEX
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_and_disallowed_codes_mean_empty_and_complex() {
        for cell in [PIXEL, SUBPIXEL] {
            let mut simple = 0;
            for a in 0..cell.perimeter() {
                for b in 0..cell.perimeter() {
                    let c = cell.encode(a, b);
                    assert!((c as usize) < cell.codes());
                    assert_eq!(cell.ends(c), (a.min(b), a.max(b)));
                    let different_sides = a / cell.segments != b / cell.segments;
                    assert_eq!(cell.is_simple(c), different_sides);
                    if different_sides && a < b {
                        simple += 1;
                        assert!(c != EMPTY && c != COMPLEX);
                    }
                }
            }
            // 6 side pairs x S^2 positions.
            assert_eq!(simple, 6 * cell.segments * cell.segments);
            assert!(!cell.is_simple(EMPTY) && !cell.is_simple(COMPLEX));
        }
        assert_eq!(PIXEL.codes(), 1024);
    }

    #[test]
    fn classification_counts_crossings_and_sides() {
        let c = PIXEL;
        assert_eq!(c.classify(0), EMPTY);
        // One crossing (an edge ends inside the pixel): complex.
        assert_eq!(c.classify(1 << 3), COMPLEX);
        // Top segment 2 and left segment 5: simple.
        let m = pixel_mask(1 << 2, 0, 0, 1 << 5);
        assert_eq!(c.classify(m), c.encode(2, 3 * 8 + 5));
        // Two crossings on the same side: complex.
        assert_eq!(c.classify(pixel_mask(0b101, 0, 0, 0)), COMPLEX);
        // Three crossings: complex.
        assert_eq!(c.classify(pixel_mask(1, 1, 1, 0)), COMPLEX);
        // Subpixel masks are 4 bits per side.
        let s = SUBPIXEL;
        assert_eq!(s.classify((1 << 1) | (1 << (2 * 4 + 3))), s.encode(1, 11));
    }

    #[test]
    fn regions_and_epi_pixel_packing() {
        assert_eq!(PIXEL.region_of(0.0, 0.0), 0);
        assert_eq!(PIXEL.region_of(0.99, 0.3), 3 + 4);
        assert_eq!(PIXEL.region_of(0.26, 0.999), 1 + 12);
        assert_eq!(PIXEL.region_of(f32::NAN, 2.0), 12);
        assert_eq!(PIXEL.region_of(-0.5, 0.999_999_9), 12);
        // Against floor(t * 4) everywhere on a fine grid.
        for i in 0..4096 {
            let t = i as f32 / 4096.0;
            assert_eq!(PIXEL.region_of(t, 0.0), (t * 4.0) as u32, "{t}");
            assert_eq!(SUBPIXEL.region_of(0.0, t), 2 * (t * 2.0) as u32, "{t}");
        }
        let p = EpiPixel::new(PIXEL.encode(2, 29), 13, true, true);
        assert_eq!((p.code(), p.region(), p.usable(), p.primary_b()), (PIXEL.encode(2, 29), 13, true, true));
        assert!(p.is_simple() && !p.is_empty() && !p.is_complex());
        let e = EpiPixel::new(EMPTY, 0, false, false);
        assert!(e.is_empty() && !e.usable());
        assert!(EpiPixel::new(COMPLEX, 5, false, false).is_complex());
    }
}
