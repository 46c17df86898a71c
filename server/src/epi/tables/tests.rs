//! The tables against direct geometric computation on random edges.
use super::*;
use crate::epi::testutil::Rng;

/// A random point on perimeter segment `p` of `cell`.
fn on_segment(cell: Cell, p: u32, rng: &mut Rng) -> [f64; 2] {
    let [s, e] = cell.segment(p);
    let t = rng.f64();
    [s[0] + t * (e[0] - s[0]), s[1] + t * (e[1] - s[1])]
}

fn in_square(lo: [f64; 2], hi: [f64; 2], rng: &mut Rng) -> [f64; 2] {
    [lo[0] + rng.f64() * (hi[0] - lo[0]), lo[1] + rng.f64() * (hi[1] - lo[1])]
}

fn simple_codes(cell: Cell) -> Vec<u16> {
    (0..cell.codes() as u16).filter(|&c| cell.is_simple(c)).collect()
}

#[test]
fn side_table_agrees_with_every_true_edge_in_the_quantisation_band() {
    let t = tables();
    let mut rng = Rng(1);
    for ct in [&t.pixel, &t.subpixel] {
        let cell = ct.cell;
        let (mut a, mut b, mut amb) = (0, 0, 0);
        for code in simple_codes(cell) {
            let (ea, eb) = cell.ends(code);
            let (p, q) = (cell.boundary_point(ea), cell.boundary_point(eb));
            for r in 0..cell.region_count() as u32 {
                let (lo, hi) = cell.region_square(r);
                let centre = [(lo[0] + hi[0]) * 0.5, (lo[1] + hi[1]) * 0.5];
                let s = ct.side(code, r);
                match s {
                    SIDE_A | SIDE_B => {
                        // Every true edge (ends anywhere on the two crossed segments) leaves
                        // every point of the region on the table's side, and so does the
                        // quantised edge itself.
                        let want_pos = s == SIDE_A;
                        assert_eq!(orient(p, q, centre) > 0.0, want_pos, "code {code} region {r}: quantised edge");
                        for _ in 0..200 {
                            let (pe, qe) = (on_segment(cell, ea, &mut rng), on_segment(cell, eb, &mut rng));
                            let x = in_square(lo, hi, &mut rng);
                            let o = orient(pe, qe, x);
                            assert!(if want_pos { o > 0.0 } else { o < 0.0 }, "code {code} region {r}: side {s} but orient {o}");
                        }
                        if want_pos {
                            a += 1
                        } else {
                            b += 1
                        }
                    }
                    _ => {
                        // Some true edge in the band crosses the region: points of the region
                        // lie on both sides of some edge. Search: random edges, plus the band's
                        // extreme edges, against the region's corners and random points.
                        let [s0, s1] = cell.segment(ea);
                        let [t0, t1] = cell.segment(eb);
                        let mut found = false;
                        let extremes = [(s0, t0), (s0, t1), (s1, t0), (s1, t1), (p, q)];
                        let corners = [lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]];
                        for k in 0..400 {
                            let (pe, qe) = if k < extremes.len() { extremes[k] } else { (on_segment(cell, ea, &mut rng), on_segment(cell, eb, &mut rng)) };
                            let (mut pos, mut neg) = (false, false);
                            for c in corners {
                                let o = orient(pe, qe, c);
                                pos |= o >= 0.0;
                                neg |= o <= 0.0;
                            }
                            if pos && neg {
                                found = true;
                                break;
                            }
                        }
                        assert!(found, "code {code} region {r}: ambiguous but no edge in the band crosses it");
                        amb += 1;
                    }
                }
            }
        }
        // Both sides occur about equally, and ambiguity is the exception.
        assert!(a > 0 && b > 0 && amb > 0);
        if cell == PIXEL {
            assert!(amb < (a + b), "{amb} ambiguous vs {a} + {b}");
        }
        // Empty cells put every sample on side A; complex cells make every sample unusable.
        for r in 0..cell.region_count() as u32 {
            assert_eq!(ct.side(crate::epi::code::EMPTY, r), SIDE_A);
            assert_eq!(ct.side(crate::epi::code::COMPLEX, r), AMBIGUOUS);
        }
    }
}

#[test]
fn exact_point_sides_agree_with_the_band_and_the_region_table() {
    let t = tables();
    let mut rng = Rng(2);
    for ct in [&t.pixel, &t.subpixel] {
        let cell = ct.cell;
        for code in simple_codes(cell) {
            let (ea, eb) = cell.ends(code);
            for _ in 0..20 {
                let r = [rng.f64(), rng.f64()];
                let s = ct.side_of_point(code, r);
                let region = cell.region_of(r[0] as f32, r[1] as f32);
                // A region on one side puts each of its points there.
                if ct.side(code, region) != AMBIGUOUS {
                    assert_eq!(s, ct.side(code, region));
                }
                let mut seen = [false; 2];
                for _ in 0..50 {
                    let o = orient(on_segment(cell, ea, &mut rng), on_segment(cell, eb, &mut rng), r);
                    seen[usize::from(o < 0.0)] = true;
                }
                match s {
                    SIDE_A => assert!(!seen[1]),
                    SIDE_B => assert!(!seen[0]),
                    _ => {}
                }
            }
        }
    }
}

#[test]
fn region_areas_match_a_fine_grid() {
    let t = tables();
    const N: usize = 200;
    for ct in [&t.pixel, &t.subpixel] {
        for code in simple_codes(ct.cell) {
            let (ea, eb) = ct.cell.ends(code);
            let (p, q) = (ct.cell.boundary_point(ea), ct.cell.boundary_point(eb));
            let mut count = 0;
            for i in 0..N {
                for j in 0..N {
                    let x = [(i as f64 + 0.5) / N as f64, (j as f64 + 0.5) / N as f64];
                    count += usize::from(orient(p, q, x) > 0.0);
                }
            }
            let grid = count as f64 / (N * N) as f64;
            assert!((grid - ct.area_a(code) as f64).abs() < 0.01, "code {code}: table {} grid {grid}", ct.area_a(code));
        }
        assert_eq!(ct.area_a(crate::epi::code::EMPTY), 1.0);
    }
}

/// A random cell content for the neighbour test: empty, or a simple edge with one end on
/// the shared side (at `shared_pos`) or none there.
struct RandomCell {
    code: u16,
    primary_b: bool,
}

/// Random simple or empty cell; if `through` is `Some(pos)`, the edge crosses the side
/// `shared` at `pos`, otherwise it avoids that side.
fn random_cell(cell: Cell, shared: u32, through: Option<u32>, rng: &mut Rng) -> RandomCell {
    let s = cell.segments;
    match through {
        None if rng.chance(0.3) => RandomCell { code: crate::epi::code::EMPTY, primary_b: false },
        None => loop {
            let (a, b) = (rng.below(4 * s as usize) as u32, rng.below(4 * s as usize) as u32);
            if a / s != b / s && a / s != shared && b / s != shared {
                return RandomCell { code: cell.encode(a, b), primary_b: rng.chance(0.5) };
            }
        },
        Some(pos) => loop {
            let b = rng.below(4 * s as usize) as u32;
            if b / s != shared {
                return RandomCell { code: cell.encode(shared * s + pos, b), primary_b: rng.chance(0.5) };
            }
        },
    }
}

/// Region (0 primary, 1 secondary) of `x` in a cell.
fn region_of(cell: Cell, c: &RandomCell, x: [f64; 2]) -> usize {
    if !cell.is_simple(c.code) {
        return 0;
    }
    let (ea, eb) = cell.ends(c.code);
    let on_b = orient(cell.boundary_point(ea), cell.boundary_point(eb), x) < 0.0;
    usize::from(on_b != c.primary_b)
}

#[test]
fn neighbour_tables_match_regions_meeting_along_the_shared_side_of_random_edges() {
    let t = tables();
    let mut rng = Rng(7);
    for (ct, cell) in [(&t.pixel, PIXEL), (&t.subpixel, SUBPIXEL)] {
        for d in 0..4 {
            let (sa, sb) = (shared_side(d), shared_side((d + 2) % 4));
            let mut seen = std::collections::HashSet::new();
            for _ in 0..3000 {
                // Neighbours share the crossings of their shared side: both cross it at the
                // same segment, or neither does.
                let through = rng.chance(0.5).then(|| rng.below(cell.segments as usize) as u32);
                let (a, b) = (random_cell(cell, sa, through, &mut rng), random_cell(cell, sb, through, &mut rng));
                // The shared crossing as the true edges would have it: anywhere in the segment.
                let mut oracle = 0u8;
                for k in 0..1000 {
                    let u = (k as f64 + 0.5) / 1000.0;
                    if let Some(pos) = through {
                        let x = (pos as f64 + 0.5) / cell.segments as f64;
                        if (u - x).abs() < 1e-9 {
                            continue;
                        }
                    }
                    let (ra, rb) = (region_of(cell, &a, side_point(sa, u)), region_of(cell, &b, side_point(sb, u)));
                    oracle |= 1 << (2 * ra + rb);
                }
                let (ca, cb) = (ct.class4(a.code, a.primary_b), ct.class4(b.code, b.primary_b));
                assert_eq!(t.neighbour(d, ca, cb), oracle, "direction {d}: codes {} / {} (4-bit {ca} / {cb})", a.code, b.code);
                seen.insert((ca, cb));
            }
            assert!(seen.len() > 60, "direction {d}: {} code pairs exercised", seen.len());
        }
    }
    // Complex cells (and invalid codes) block in every direction.
    for d in 0..4 {
        for x in 0..16u8 {
            assert_eq!(t.neighbour(d, CLASS_COMPLEX, x), 0);
            assert_eq!(t.neighbour(d, x, CLASS_COMPLEX), 0);
        }
    }
}

#[test]
fn neighbour_tables_are_topological_and_reverse_by_transposition() {
    let t = tables();
    for d in 0..4 {
        // Generated from subpixel geometry they are the same.
        assert_eq!(neighbour_table(SUBPIXEL, d), t.neighbour[d]);
        // Looking from the other cell transposes the mask.
        for a in 0..16u8 {
            for b in 0..16u8 {
                assert_eq!(t.neighbour(d, a, b), transpose(t.neighbour((d + 2) % 4, b, a)));
            }
        }
    }
    // Two empty cells: primary to primary only.
    assert_eq!(t.neighbour(DIR_RIGHT, CLASS_EMPTY, CLASS_EMPTY), PP);
}

#[test]
fn chaining_is_the_boolean_matrix_product() {
    let t = tables();
    for ab in 0..16u8 {
        for bd in 0..16u8 {
            let m = |x: u8, i: usize, j: usize| (x >> (2 * i + j)) & 1 == 1;
            let mut want = 0u8;
            for i in 0..2 {
                for k in 0..2 {
                    if (0..2).any(|j| m(ab, i, j) && m(bd, j, k)) {
                        want |= 1 << (2 * i + k);
                    }
                }
            }
            assert_eq!(t.chain(ab, bd), want);
            // Chaining backwards is the transposed product.
            assert_eq!(transpose(t.chain(ab, bd)), t.chain(transpose(bd), transpose(ab)));
        }
    }
}

#[test]
fn anti_aliasing_candidates_lie_on_the_secondary_side_deepest_first() {
    let t = tables();
    for code in simple_codes(PIXEL) {
        let (ea, eb) = PIXEL.ends(code);
        let (p, q) = (PIXEL.boundary_point(ea), PIXEL.boundary_point(eb));
        for secondary_b in [false, true] {
            let c = t.pixel.aa_candidates(code, secondary_b);
            let mut last = f64::INFINITY;
            let mut n = 0;
            for &d in c.iter().take_while(|&&d| d != 0xFF) {
                let (dx, dy) = DIRS[d as usize];
                let o = orient(p, q, [0.5 + dx as f64, 0.5 + dy as f64]);
                assert!(if secondary_b { o < 0.0 } else { o > 0.0 }, "code {code}: candidate {d} on the wrong side");
                assert!(o.abs() <= last);
                last = o.abs();
                n += 1;
            }
            // A line through the pixel leaves at least one neighbour centre on each side.
            assert!(n >= 1, "code {code} secondary_b {secondary_b}: no candidate");
            // All neighbour centres on that side are listed.
            let all = DIRS.iter().filter(|&&(dx, dy)| {
                let o = orient(p, q, [0.5 + dx as f64, 0.5 + dy as f64]);
                if secondary_b { o < 0.0 } else { o > 0.0 }
            });
            assert_eq!(all.count(), n);
        }
    }
    assert!(tables().bytes() < 64 * 1024);
}
