//! Deterministic randomness for the EPI tests.
#![cfg(test)]

pub use crate::rng::Rng;

use super::raster::fine_position;
use super::Epi;
use crate::render_cache::{PointImage, NO_POINT};
use glam::Vec3;

/// Eighth of [0, 1) holding `f`.
fn eighth(f: f64) -> u32 {
    ((f * 8.0) as u32).min(7)
}

/// The crossings' fine positions and the segment-end bits of
/// [`super::raster::Boundaries`], or none (empty: the anti-aliasing uses quantised areas).
#[derive(Default)]
pub struct Fine {
    pub positions: Vec<u16>,
    pub ends: Vec<u64>,
}

impl Fine {
    pub fn new(w: usize, h: usize) -> Self {
        Fine { positions: vec![0; (w + 1) * (h + 1)], ends: vec![0; h * w.div_ceil(64)] }
    }
}

/// Records the crossings of the 2D segment `a`-`b` (pixel coordinates) with the boundary
/// lines of a `w` x `h` image (and the centre lines when `centres` is not empty), and their
/// fine positions and the segment's ends when `fine` has them, as the rasterizer does.
pub fn draw_segment(w: usize, h: usize, sides: &mut [u16], centres: &mut [u16], fine: &mut Fine, a: [f64; 2], b: [f64; 2]) {
    if !fine.ends.is_empty() {
        for [x, y] in [a, b] {
            if x >= 0.0 && y >= 0.0 && x < w as f64 && y < h as f64 {
                fine.ends[y as usize * w.div_ceil(64) + x as usize / 64] |= 1 << (x as usize % 64);
            }
        }
    }
    let d = [b[0] - a[0], b[1] - a[1]];
    for (offset, centre) in [(0.0, false), (0.5, true)] {
        if centre && centres.is_empty() {
            continue;
        }
        // Axis 0: vertical lines x = l (+ offset), crossings at y; axis 1: horizontal lines.
        for axis in 0..2 {
            let (u, v) = (axis, 1 - axis);
            if d[u] == 0.0 {
                continue;
            }
            let (lines, across) = if axis == 0 { (w, h) } else { (h, w) };
            let (lo, hi) = (a[u].min(b[u]) - offset, a[u].max(b[u]) - offset);
            for l in lo.ceil().max(0.0) as i64..=hi.floor().min((lines - usize::from(centre)) as f64) as i64 {
                let t = (l as f64 + offset - a[u]) / d[u];
                let q = a[v] + t * d[v];
                if q >= 0.0 && q < across as f64 {
                    let qq = q.floor();
                    let (row, col) = if axis == 0 { (qq as usize, l as usize) } else { (l as usize, qq as usize) };
                    let bit = 1u16 << (8 * axis as u32 + eighth(q - qq));
                    if centre {
                        centres[row * w + col] |= bit;
                    } else {
                        sides[row * (w + 1) + col] |= bit;
                        if let Some(f) = fine.positions.get_mut(row * (w + 1) + col) {
                            let fq = fine_position(q - qq);
                            assert_eq!(fq >> 8, eighth(q - qq));
                            let byte = (fq & 0xFF) as u16;
                            *f = if axis == 0 { (*f & 0xFF00) | byte } else { (*f & 0x00FF) | byte << 8 };
                        }
                    }
                }
            }
        }
    }
}

/// A random point image: each pixel holds a point with probability `density`, at a random
/// position inside it, with a random colour.
pub fn random_points(w: usize, h: usize, density: f64, rng: &mut Rng) -> PointImage {
    let mut pi = PointImage { width: w as u32, height: h as u32, ..Default::default() };
    for i in 0..w * h {
        let has = rng.chance(density);
        pi.point.push(if has { i as u32 } else { NO_POINT });
        pi.depth.push(if has { 1.0 + rng.unit() } else { f32::INFINITY });
        pi.subpixel.push([rng.unit(), rng.unit()]);
        pi.color.push(if has { Vec3::new(rng.unit(), rng.unit(), rng.unit()) } else { Vec3::ZERO });
        pi.age.push(if has { 1.0 } else { f32::INFINITY });
    }
    pi
}

/// A random EPI over `points`: `long` lines across the image (chains of simple pixels,
/// crossings making complex ones) and `short` segments (ends inside pixels: complex).
pub fn random_epi(points: &PointImage, long: usize, short: usize, centre_lines: bool, rng: &mut Rng) -> Epi {
    let (w, h) = (points.width as usize, points.height as usize);
    let mut sides = vec![0u16; (w + 1) * (h + 1)];
    let mut centres = if centre_lines { vec![0u16; w * h] } else { Vec::new() };
    let mut fine = Fine::new(w, h);
    let (wf, hf) = (w as f64, h as f64);
    for k in 0..long + short {
        let a = [rng.f64() * (wf + 4.0) - 2.0, rng.f64() * (hf + 4.0) - 2.0];
        let b = if k < long {
            [rng.f64() * (wf + 4.0) - 2.0, rng.f64() * (hf + 4.0) - 2.0]
        } else {
            [a[0] + rng.f64() * 6.0 - 3.0, a[1] + rng.f64() * 6.0 - 3.0]
        };
        draw_segment(w, h, &mut sides, &mut centres, &mut fine, a, b);
    }
    let mut epi = Epi::new(w as u32, h as u32);
    epi.classify_with(sides, centres, fine, points);
    epi
}

/// All monotone lattice paths from (0, 0) to (dx, dy), as offset lists (the "reasonably
/// direct" paths of paper 000 §5.2).
pub fn monotone_paths(dx: i64, dy: i64) -> Vec<Vec<(i64, i64)>> {
    if dx == 0 && dy == 0 {
        return vec![vec![(0, 0)]];
    }
    let mut out = Vec::new();
    if dx != 0 {
        for mut p in monotone_paths(dx - dx.signum(), dy) {
            p.push((dx, dy));
            out.push(p);
        }
    }
    if dy != 0 {
        for mut p in monotone_paths(dx, dy - dy.signum()) {
            p.push((dx, dy));
            out.push(p);
        }
    }
    out
}

/// The pairs (region of cell a, region of cell b) that meet along the side the two cells
/// share, cell b lying at `d` from cell a; `region_a` / `region_b` give the region (or
/// `None` for a complex cell) of a point in each cell's unit square. Tested at `steps`
/// points along the side, never exactly at a crossing ((p + 1/2) / 8 of the side).
pub fn regions_meeting(region_a: impl Fn([f64; 2]) -> Option<usize>, region_b: impl Fn([f64; 2]) -> Option<usize>, d: (i64, i64), steps: usize) -> Vec<(usize, usize)> {
    let mut out = std::collections::HashSet::new();
    for k in 0..steps {
        let t = (k as f64 + 0.37) / steps as f64;
        let (pa, pb) = match d {
            (1, 0) => ([1.0, t], [0.0, t]),
            (-1, 0) => ([0.0, t], [1.0, t]),
            (0, 1) => ([t, 1.0], [t, 0.0]),
            _ => ([t, 0.0], [t, 1.0]),
        };
        if let (Some(x), Some(y)) = (region_a(pa), region_b(pb)) {
            out.insert((x, y));
        }
    }
    out.into_iter().collect()
}
