//! Reachability against a brute-force flood fill over the regions of random EPIs, along
//! every monotone path of the 5 × 5 window.
use super::*;
use crate::epi::code::{EpiPixel, PIXEL};
use crate::epi::tables::orient;
use crate::epi::testutil::{monotone_paths, random_epi, random_points, regions_meeting, Rng};
use crate::epi::Epi;
use std::collections::{HashSet, VecDeque};


/// Region (0 primary, 1 secondary) of cell point `r` in a pixel; `None` for complex pixels.
fn region(p: EpiPixel, r: [f64; 2]) -> Option<usize> {
    if p.is_complex() {
        return None;
    }
    if p.is_empty() {
        return Some(0);
    }
    let (a, b) = PIXEL.ends(p.code());
    let on_b = orient(PIXEL.boundary_point(a), PIXEL.boundary_point(b), r) < 0.0;
    Some(usize::from(on_b != p.primary_b()))
}

/// Region pairs meeting along the shared side of 4-neighbours `a` and `b` (b at `d` from a),
/// each pixel's region decided by its own quantised edge.
fn meeting(pa: EpiPixel, pb: EpiPixel, d: (i64, i64)) -> Vec<(usize, usize)> {
    regions_meeting(|r| region(pa, r), |r| region(pb, r), d, 200)
}

/// Whether the primary region of `c` reaches the primary region of `c + o` by flood fill
/// over the regions of the pixels of some monotone path.
fn oracle(epi: &Epi, cx: i64, cy: i64, o: (i64, i64)) -> bool {
    let (w, h) = (epi.width() as i64, epi.height() as i64);
    let px = |x: i64, y: i64| epi.pixels()[(y * w + x) as usize];
    let (tx, ty) = (cx + o.0, cy + o.1);
    if tx < 0 || ty < 0 || tx >= w || ty >= h || px(cx, cy).is_complex() || px(tx, ty).is_complex() {
        return false;
    }
    for path in monotone_paths(o.0, o.1) {
        let cells: Vec<(i64, i64)> = path.iter().map(|&(dx, dy)| (cx + dx, cy + dy)).collect();
        if cells.iter().any(|&(x, y)| x < 0 || y < 0 || x >= w || y >= h) {
            continue;
        }
        let on_path: HashSet<(i64, i64)> = cells.iter().copied().collect();
        let mut seen = HashSet::new();
        let mut queue = VecDeque::from([((cx, cy), 0usize)]);
        seen.insert(((cx, cy), 0usize));
        while let Some(((x, y), r)) = queue.pop_front() {
            if (x, y) == (tx, ty) && r == 0 {
                return true;
            }
            for d in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                let n = (x + d.0, y + d.1);
                if !on_path.contains(&n) {
                    continue;
                }
                for (ra, rb) in meeting(px(x, y), px(n.0, n.1), d) {
                    if ra == r && seen.insert((n, rb)) {
                        queue.push_back((n, rb));
                    }
                }
            }
        }
    }
    false
}

#[test]
fn reachability_matches_flood_fill_along_monotone_paths_on_random_epis() {
    let mut rng = Rng(21);
    let mut checked = (0usize, 0usize);
    for (w, h, long, short) in [(17, 13, 4, 4), (70, 9, 6, 8), (9, 23, 3, 10), (130, 6, 10, 10)] {
        let points = random_points(w, h, 0.5, &mut rng);
        let mut epi = random_epi(&points, long, short, false, &mut rng);
        let c = *epi.counts();
        assert!(c.simple > 10 && c.complex > 3 && c.empty > 10, "{c:?}");
        epi.neighbours.compute(&epi.pixels, &epi.flags);
        epi.reach.compute(&epi.neighbours, &epi.flags);
        let mut per_pixel = scalar::ScalarReach::new(w, h);
        per_pixel.compute(&epi.pixels);
        for y in 0..h {
            for x in 0..w {
                let m = epi.reach.mask24(x, y);
                assert_eq!(per_pixel.mask24(x, y), m, "{w}x{h}: pixel ({x},{y}): per-pixel and bit-sliced differ");
                for k in (0..25).filter(|&k| k != 12) {
                    let (dx, dy) = offset(k);
                    let want = oracle(&epi, x as i64, y as i64, (dx as i64, dy as i64));
                    let got = (m >> mask_bit(k)) & 1 == 1;
                    assert_eq!(got, want, "{w}x{h}: pixel ({x},{y}) offset ({dx},{dy}): {:?}", epi.pixels[y * w + x]);
                    checked.0 += 1;
                    checked.1 += usize::from(want);
                }
            }
        }
    }
    // Both answers are common.
    assert!(checked.1 > checked.0 / 4 && checked.1 < checked.0 * 9 / 10, "{checked:?}");
}

#[test]
fn reachability_is_symmetric() {
    let mut rng = Rng(5);
    let points = random_points(40, 30, 0.3, &mut rng);
    let mut epi = random_epi(&points, 8, 12, false, &mut rng);
    epi.neighbours.compute(&epi.pixels, &epi.flags);
    epi.reach.compute(&epi.neighbours, &epi.flags);
    for y in 0..30i64 {
        for x in 0..40i64 {
            let m = epi.reach.mask24(x as usize, y as usize);
            for k in (0..25).filter(|&k| k != 12) {
                let (dx, dy) = offset(k);
                let (px, py) = (x + dx as i64, y + dy as i64);
                if px < 0 || py < 0 || px >= 40 || py >= 30 {
                    assert_eq!((m >> mask_bit(k)) & 1, 0, "outside the image");
                    continue;
                }
                let back = epi.reach.mask24(px as usize, py as usize);
                assert_eq!((m >> mask_bit(k)) & 1, (back >> mask_bit(24 - k)) & 1);
            }
        }
    }
}

#[test]
fn an_edge_free_image_reaches_its_whole_window() {
    let mut rng = Rng(9);
    let points = random_points(100, 7, 0.5, &mut rng);
    let mut epi = random_epi(&points, 0, 0, false, &mut rng);
    epi.neighbours.compute(&epi.pixels, &epi.flags);
    epi.reach.compute(&epi.neighbours, &epi.flags);
    for y in 0..7usize {
        for x in 0..100usize {
            let mut want = 0;
            for k in (0..25).filter(|&k| k != 12) {
                let (dx, dy) = offset(k);
                let (px, py) = (x as i64 + dx as i64, y as i64 + dy as i64);
                if px >= 0 && py >= 0 && px < 100 && py < 7 {
                    want |= 1 << mask_bit(k);
                }
            }
            assert_eq!(epi.reach.mask24(x, y), want, "({x},{y})");
        }
    }
}

