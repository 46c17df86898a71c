//! The lookup tables of paper 000 §4.3 and §5.1–5.3, all generated once at start-up from the
//! cell geometry of [`super::code`] (never typed in):
//!
//! - **side of edge** (§4.3): (edge code, sample region) → side A, side B or
//!   edge-ambiguous. Side A is the left of the directed edge from its lower perimeter index
//!   to its higher one (`orient > 0` in image coordinates). A region is ambiguous when the
//!   quantised edge, widened by its quantisation error, crosses it (DESIGN.md): the true
//!   edge ends anywhere on the two crossed boundary segments, and the region is on one side
//!   only if every such edge leaves the whole region on that side. `orient(P, Q, r)` is
//!   affine in each of `P`, `Q` and `r` separately, so it is enough to test the segment
//!   ends and the region corners (2 × 2 × 4 evaluations): the test is exact.
//! - **region areas** (§5.1, §5.3 anti-aliasing): area of side A of the quantised edge.
//! - **4-bit neighbour codes** (§5.2): empty (0), complex (1), or simple with its side pair
//!   (6 pairs) and which side is primary: `2 + 2 * pair + primary_is_b`.
//! - **neighbour tables** (§5.2), one per shared-side direction: two 4-bit codes → the 4-bit
//!   reachability mask (Pa↔Pb, Pa↔Sb, Sa↔Pb, Sa↔Sb) across the shared side. Neighbours
//!   share their crossing of the shared side, so the answer depends only on which sides
//!   each edge crosses: the table is generated from one representative edge per code, with
//!   the shared crossing at the same place in both cells, by testing which regions meet at
//!   points along the shared side. The tests check it against random edges.
//! - **chaining table** (§5.2): two masks a↔b and b↔d → a↔d through either region of b
//!   (a boolean 2 × 2 matrix product).
//! - **anti-aliasing neighbour order** (§5.3): per edge code and secondary side, the
//!   4-neighbours whose centres lie on the secondary side of the edge, deepest first.
//!
//! The neighbour and chaining tables are the same for pixels and for the complex filter's
//! subpixels (they depend only on topology); the cell tables exist for both.
use super::code::{Cell, BOTTOM, EMPTY, LEFT, PIXEL, RIGHT, SUBPIXEL, TOP};
use std::sync::OnceLock;

/// Sample side: the sample lies on side A of the edge (or the cell is empty).
pub const SIDE_A: u8 = 0;
/// The sample lies on side B of the edge.
pub const SIDE_B: u8 = 1;
/// The sample is edge-ambiguous (or the cell is complex): it cannot be used.
pub const AMBIGUOUS: u8 = 2;

/// Reachability mask bits: (Pa↔Pb, Pa↔Sb, Sa↔Pb, Sa↔Sb). Bit index = `2 * ra + rb` with
/// region 0 = primary, 1 = secondary.
pub const PP: u8 = 1;
pub const PS: u8 = 2;
pub const SP: u8 = 4;
pub const SS: u8 = 8;

/// Neighbour directions (the neighbour's offset from the cell): right, down, left, up.
pub const DIRS: [(i32, i32); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];
pub const DIR_RIGHT: usize = 0;
pub const DIR_DOWN: usize = 1;
pub const DIR_LEFT: usize = 2;
pub const DIR_UP: usize = 3;

/// The side of a cell facing the neighbour in direction `d`.
pub const fn shared_side(d: usize) -> u32 {
    match d {
        DIR_RIGHT => RIGHT,
        DIR_DOWN => BOTTOM,
        DIR_LEFT => LEFT,
        _ => TOP,
    }
}

/// The side pairs of simple edges, in 4-bit-code order.
pub const SIDE_PAIRS: [(u32, u32); 6] = [(TOP, RIGHT), (TOP, BOTTOM), (TOP, LEFT), (RIGHT, BOTTOM), (RIGHT, LEFT), (BOTTOM, LEFT)];

/// 4-bit neighbour code of an empty cell.
pub const CLASS_EMPTY: u8 = 0;
/// 4-bit neighbour code of a complex cell (and of anything outside the image).
pub const CLASS_COMPLEX: u8 = 1;

/// `orient(p, q, r) > 0`: `r` on side A of the directed line `p → q`.
#[inline]
pub fn orient(p: [f64; 2], q: [f64; 2], r: [f64; 2]) -> f64 {
    (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
}

/// Swaps the roles of the two cells of a mask: (Pa↔Pb, Pa↔Sb, Sa↔Pb, Sa↔Sb) →
/// (Pb↔Pa, Pb↔Sa, Sb↔Pa, Sb↔Sa).
#[inline]
pub const fn transpose(m: u8) -> u8 {
    (m & (PP | SS)) | ((m & PS) << 1) | ((m & SP) >> 1)
}

/// Boolean product of two masks: a↔d through b, over both regions of b.
pub const fn chain_masks(ab: u8, bd: u8) -> u8 {
    let mut out = 0;
    let mut i = 0;
    while i < 2 {
        let mut k = 0;
        while k < 2 {
            let mut j = 0;
            while j < 2 {
                if (ab >> (2 * i + j)) & 1 != 0 && (bd >> (2 * j + k)) & 1 != 0 {
                    out |= 1 << (2 * i + k);
                }
                j += 1;
            }
            k += 1;
        }
        i += 1;
    }
    out
}

/// The tables of one cell geometry.
pub struct CellTables {
    pub cell: Cell,
    /// `side[code * regions + region]`.
    side: Vec<u8>,
    /// Area of side A of the quantised edge (1 for empty and complex codes).
    area_a: Vec<f32>,
    /// 4-bit neighbour code without the primary bit (`2 + 2 * pair` for simple codes).
    class_base: Vec<u8>,
    /// `aa_order[2 * code + secondary_is_b]`: neighbour directions, deepest first, `0xFF` end.
    aa_order: Vec<[u8; 4]>,
}

impl CellTables {
    fn build(cell: Cell) -> Self {
        let codes = cell.codes();
        let regions = cell.region_count();
        let mut side = vec![AMBIGUOUS; codes * regions];
        let mut area_a = vec![1.0f32; codes];
        let mut class_base = vec![CLASS_COMPLEX; codes];
        let mut aa_order = vec![[0xFFu8; 4]; codes * 2];
        side[EMPTY as usize * regions..(EMPTY as usize + 1) * regions].fill(SIDE_A);
        class_base[EMPTY as usize] = CLASS_EMPTY;
        for code in 0..codes as u16 {
            if !cell.is_simple(code) {
                continue;
            }
            let (a, b) = cell.ends(code);
            let (sa, sb) = (a / cell.segments, b / cell.segments);
            let pair = SIDE_PAIRS.iter().position(|&p| p == (sa, sb)).expect("ends are in side order");
            class_base[code as usize] = 2 + 2 * pair as u8;
            let (p, q) = (cell.boundary_point(a), cell.boundary_point(b));
            area_a[code as usize] = side_a_area(p, q) as f32;
            let (pa, pb) = (cell.segment(a), cell.segment(b));
            for r in 0..regions as u32 {
                let (lo, hi) = cell.region_square(r);
                let corners = [lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]];
                let (mut pos, mut neg) = (false, false);
                for pe in pa {
                    for qe in pb {
                        for c in corners {
                            let o = orient(pe, qe, c);
                            pos |= o >= 0.0;
                            neg |= o <= 0.0;
                        }
                    }
                }
                side[code as usize * regions + r as usize] = match (pos, neg) {
                    (true, false) => SIDE_A,
                    (false, true) => SIDE_B,
                    _ => AMBIGUOUS,
                };
            }
            for secondary_b in [false, true] {
                let mut cands: Vec<(f64, u8)> = DIRS
                    .iter()
                    .enumerate()
                    .filter_map(|(d, &(dx, dy))| {
                        let o = orient(p, q, [0.5 + dx as f64, 0.5 + dy as f64]);
                        let on_secondary = if secondary_b { o < 0.0 } else { o > 0.0 };
                        on_secondary.then_some((o.abs(), d as u8))
                    })
                    .collect();
                cands.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
                let slot = &mut aa_order[2 * code as usize + secondary_b as usize];
                for (i, &(_, d)) in cands.iter().enumerate() {
                    slot[i] = d;
                }
            }
        }
        CellTables { cell, side, area_a, class_base, aa_order }
    }

    /// Side of a sample in `region` for a cell with `code`: [`SIDE_A`], [`SIDE_B`] or
    /// [`AMBIGUOUS`] (always ambiguous for complex cells, side A for empty ones).
    #[inline]
    pub fn side(&self, code: u16, region: u32) -> u8 {
        self.side[code as usize * self.cell.region_count() + region as usize]
    }

    /// Side of a sample at the exact cell position `r` (rather than its region): A or B when
    /// every edge of the quantisation band leaves `r` on that side, else ambiguous. The
    /// complex filter uses this: its subpixel regions are half a subpixel wide, as wide as
    /// the band itself, so nearly every region would be ambiguous.
    pub fn side_of_point(&self, code: u16, r: [f64; 2]) -> u8 {
        if code == EMPTY {
            return SIDE_A;
        }
        if !self.cell.is_simple(code) {
            return AMBIGUOUS;
        }
        let (a, b) = self.cell.ends(code);
        let (mut pos, mut neg) = (false, false);
        for pe in self.cell.segment(a) {
            for qe in self.cell.segment(b) {
                let o = orient(pe, qe, r);
                pos |= o >= 0.0;
                neg |= o <= 0.0;
            }
        }
        match (pos, neg) {
            (true, false) => SIDE_A,
            (false, true) => SIDE_B,
            _ => AMBIGUOUS,
        }
    }

    /// Area of side A of the quantised edge of `code` within the unit cell.
    #[inline]
    pub fn area_a(&self, code: u16) -> f32 {
        self.area_a[code as usize]
    }

    /// The 4-bit neighbour code of a cell.
    #[inline]
    pub fn class4(&self, code: u16, primary_b: bool) -> u8 {
        let base = self.class_base[code as usize];
        base + u8::from(base >= 2 && primary_b)
    }

    /// Candidate neighbours (directions, see [`DIRS`]) for the secondary colour of a simple
    /// cell, deepest into the secondary side first; `0xFF` ends the list.
    #[inline]
    pub fn aa_candidates(&self, code: u16, secondary_b: bool) -> [u8; 4] {
        self.aa_order[2 * code as usize + secondary_b as usize]
    }
}

/// Area of the part of the unit square on side A of the line `p → q` (clipped polygon).
pub fn side_a_area(p: [f64; 2], q: [f64; 2]) -> f64 {
    let square = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    let mut poly: Vec<[f64; 2]> = Vec::with_capacity(6);
    for i in 0..4 {
        let (c, n) = (square[i], square[(i + 1) % 4]);
        let (oc, on) = (orient(p, q, c), orient(p, q, n));
        if oc >= 0.0 {
            poly.push(c);
        }
        if (oc > 0.0 && on < 0.0) || (oc < 0.0 && on > 0.0) {
            let t = oc / (oc - on);
            poly.push([c[0] + t * (n[0] - c[0]), c[1] + t * (n[1] - c[1])]);
        }
    }
    let mut a = 0.0;
    for i in 0..poly.len() {
        let (u, v) = (poly[i], poly[(i + 1) % poly.len()]);
        a += u[0] * v[1] - v[0] * u[1];
    }
    (a * 0.5).abs()
}

/// Where the representative edge of a 4-bit code crosses its sides in table generation, in
/// eighths of the side: the shared side's crossing at the same position in both cells,
/// others anywhere.
const SHARED_POS: u32 = 3;
const OTHER_POS: u32 = 4;

/// Representative edge (ends P, Q) and primary side of a simple 4-bit code for a cell whose
/// side `shared` faces the neighbour; `None` for empty. Complex codes never get here.
fn representative(cell: Cell, c4: u8, shared: u32) -> Option<([f64; 2], [f64; 2], bool)> {
    if c4 == CLASS_EMPTY {
        return None;
    }
    let pair = (c4 - 2) / 2;
    let primary_b = (c4 - 2) & 1 == 1;
    let (sa, sb) = SIDE_PAIRS[pair as usize];
    let pos = |s: u32| if s == shared { SHARED_POS * cell.segments / 8 } else { OTHER_POS * cell.segments / 8 };
    let (a, b) = (sa * cell.segments + pos(sa), sb * cell.segments + pos(sb));
    Some((cell.boundary_point(a), cell.boundary_point(b), primary_b))
}

/// Point `t` of side `side` in cell coordinates.
fn side_point(side: u32, t: f64) -> [f64; 2] {
    match side {
        TOP => [t, 0.0],
        RIGHT => [1.0, t],
        BOTTOM => [t, 1.0],
        _ => [0.0, t],
    }
}

/// Region (0 primary, 1 secondary) of point `r` in a cell with representative edge `e`.
fn region_at(e: Option<([f64; 2], [f64; 2], bool)>, r: [f64; 2]) -> usize {
    match e {
        None => 0,
        Some((p, q, primary_b)) => {
            let on_b = orient(p, q, r) < 0.0;
            usize::from(on_b != primary_b)
        }
    }
}

/// The neighbour table for direction `d` (the neighbour `b` lies at `DIRS[d]` from `a`),
/// generated with the representative edges of `cell`.
pub fn neighbour_table(cell: Cell, d: usize) -> [u8; 256] {
    let mut t = [0u8; 256];
    let (sa, sb) = (shared_side(d), shared_side((d + 2) % 4));
    for ca in 0..14u8 {
        for cb in 0..14u8 {
            if ca == CLASS_COMPLEX || cb == CLASS_COMPLEX {
                continue;
            }
            let (ea, eb) = (representative(cell, ca, sa), representative(cell, cb, sb));
            let mut m = 0u8;
            // Points along the shared side; the shared crossing (at (SHARED_POS + 1/2) / 8 of it)
            // is never one of them.
            const STEPS: u32 = 64;
            for k in 0..STEPS {
                let t = (k as f64 + 0.5) / STEPS as f64;
                let (ra, rb) = (region_at(ea, side_point(sa, t)), region_at(eb, side_point(sb, t)));
                m |= 1 << (2 * ra + rb);
            }
            t[(ca as usize) << 4 | cb as usize] = m;
        }
    }
    t
}

/// All tables.
pub struct Tables {
    pub pixel: CellTables,
    pub subpixel: CellTables,
    /// `neighbour[d][(a << 4) | b]`, see [`neighbour_table`].
    pub neighbour: [[u8; 256]; 4],
    /// `chain[(ab << 4) | bd]`.
    pub chain: [u8; 256],
}

impl Tables {
    fn build() -> Tables {
        let mut chain = [0u8; 256];
        for (i, c) in chain.iter_mut().enumerate() {
            *c = chain_masks((i >> 4) as u8, (i & 15) as u8);
        }
        Tables {
            pixel: CellTables::build(PIXEL),
            subpixel: CellTables::build(SUBPIXEL),
            neighbour: std::array::from_fn(|d| neighbour_table(PIXEL, d)),
            chain,
        }
    }

    /// Mask between a cell with 4-bit code `a` and its neighbour in direction `d` with code `b`.
    #[inline]
    pub fn neighbour(&self, d: usize, a: u8, b: u8) -> u8 {
        self.neighbour[d][(a as usize) << 4 | b as usize]
    }

    #[inline]
    pub fn chain(&self, ab: u8, bd: u8) -> u8 {
        self.chain[(ab as usize) << 4 | bd as usize]
    }

    /// Bytes of all tables.
    pub fn bytes(&self) -> usize {
        let cell = |c: &CellTables| c.side.len() + 4 * c.area_a.len() + c.class_base.len() + 4 * c.aa_order.len();
        cell(&self.pixel) + cell(&self.subpixel) + 4 * 256 + 256
    }
}

/// The tables, built on first use (about a millisecond).
pub fn tables() -> &'static Tables {
    static T: OnceLock<Tables> = OnceLock::new();
    T.get_or_init(Tables::build)
}

#[cfg(test)]
mod tests;
