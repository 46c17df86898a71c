//! Anti-aliasing against closed forms: images of two constant colours split by straight
//! edges (a line across the image, a rectangle), sampled at every pixel, reconstructed by
//! the whole pipeline. With the crossings' fine positions (as the rasterizer records them) a
//! simple pixel must show the exact box-filtered mean — the area-weighted mix of the two
//! colours with the real edge's areas, corners of rectangles included — within the fine
//! positions' rounding (2^-12 of a pixel); without them (masks from elsewhere), the mix with
//! the quantised edge's areas, within the 1/8-pixel crossing quantisation of that mean.
use crate::epi::code::{Cell, PIXEL};
use crate::epi::tables::{orient, side_a_area};
use crate::epi::testutil::{draw_segment, Fine, Rng};
use crate::epi::{Epi, InterpOptions};
use crate::render_cache::{PointImage, NO_POINT};
use crate::stage_times::StageTimes;
use glam::Vec3;

/// A point at a random position in every pixel but those `skip` names, coloured by
/// `colour_at` (image coordinates).
fn points_coloured(w: usize, h: usize, rng: &mut Rng, colour_at: impl Fn([f64; 2]) -> Vec3, skip: impl Fn(usize, usize) -> bool) -> PointImage {
    let mut pi = PointImage { width: w as u32, height: h as u32, ..Default::default() };
    for i in 0..w * h {
        let (u, v) = (rng.unit(), rng.unit());
        let has = !skip(i % w, i / w);
        pi.point.push(if has { i as u32 } else { NO_POINT });
        pi.depth.push(if has { 1.0 } else { f32::INFINITY });
        pi.subpixel.push([u, v]);
        pi.color.push(if has { colour_at([(i % w) as f64 + u as f64, (i / w) as f64 + v as f64]) } else { Vec3::ZERO });
        pi.age.push(if has { 1.0 } else { f32::INFINITY });
    }
    pi
}

/// Builds the EPI of `segments` over `points`, with the crossings' fine positions when
/// `exact`, and reconstructs it (no complex filter).
fn reconstruct(w: usize, h: usize, segments: &[([f64; 2], [f64; 2])], points: &PointImage, exact: bool) -> (Epi, Vec<Vec3>, u32) {
    let mut sides = vec![0u16; (w + 1) * (h + 1)];
    let mut fine = if exact { Fine::new(w, h) } else { Fine::default() };
    for &(a, b) in segments {
        draw_segment(w, h, &mut sides, &mut [], &mut fine, a, b);
    }
    let mut epi = Epi::new(w as u32, h as u32);
    epi.classify_with(sides, Vec::new(), fine, points);
    let (mut image, mut weights) = (vec![Vec3::ZERO; w * h], vec![0.0; w * h]);
    let rec = epi.reconstruct(points, Vec3::ZERO, &InterpOptions::default(), false, &mut image, &mut weights, &mut StageTimes::new());
    (epi, image, rec.antialiased)
}

/// For simple pixel (x, y) of a two-colour image: the colours of side A and side B of its
/// quantised edge (the colour a pixel away from the edge's midpoint on each side, beyond
/// the quantisation band even where one side is a sliver), and side A's area for the
/// quantised edge and for the four edges between the ends of the two crossed boundary
/// segments (the extremes of every edge the crossings allow: the area is affine, or
/// bilinear for adjacent sides, in the two ends' positions along their sides).
fn sides_of(cell: Cell, code: u16, x: usize, y: usize, colour_at: &impl Fn([f64; 2]) -> Vec3) -> (Vec3, Vec3, f64, [f64; 4]) {
    let (a, b) = cell.ends(code);
    let (p, q) = (cell.boundary_point(a), cell.boundary_point(b));
    let d = [q[0] - p[0], q[1] - p[1]];
    let len = d[0].hypot(d[1]);
    // The unit normal towards side A (orient > 0).
    let n = [-d[1] / len, d[0] / len];
    let m = [x as f64 + 0.5 * (p[0] + q[0]), y as f64 + 0.5 * (p[1] + q[1])];
    let ca = colour_at([m[0] + n[0], m[1] + n[1]]);
    let cb = colour_at([m[0] - n[0], m[1] - n[1]]);
    // The segments' ends pulled in by a hair: two ends on adjacent sides may be the same
    // corner, where the line through them has no direction.
    let inner = |[s, e]: [[f64; 2]; 2]| {
        let k = 1e-9;
        [[s[0] + k * (e[0] - s[0]), s[1] + k * (e[1] - s[1])], [e[0] + k * (s[0] - e[0]), e[1] + k * (s[1] - e[1])]]
    };
    let (sa, sb) = (inner(cell.segment(a)), inner(cell.segment(b)));
    let extremes = [side_a_area(sa[0], sb[0]), side_a_area(sa[0], sb[1]), side_a_area(sa[1], sb[0]), side_a_area(sa[1], sb[1])];
    (ca, cb, side_a_area(p, q), extremes)
}

/// A simple pixel of a reconstruction and what [`sides_of`] says of it.
struct Simple {
    x: usize,
    y: usize,
    at: String,
    got: Vec3,
    /// The mix with the quantised edge's areas.
    quantised: Vec3,
    area_a: f64,
    extremes: [f64; 4],
}

impl Simple {
    /// Checks the pixel against the exact box-filtered mean of a pixel covered `exact` by
    /// `inside` and otherwise by `outside`: within the crossing quantisation (the largest
    /// change of the area over the edges the crossings allow, at most 1/8).
    fn assert_within_quantisation(&self, exact: f32, inside: Vec3, outside: Vec3) {
        let exact_mean = inside * exact + outside * (1.0 - exact);
        let quantisation = self.extremes.iter().map(|e| (e - self.area_a).abs()).fold(0.0, f64::max) as f32;
        assert!(quantisation <= 1.0 / 8.0, "{}: {:?}", self.at, self.extremes);
        let bound = (inside - outside).abs() * quantisation + Vec3::splat(1e-4);
        assert!((self.got - exact_mean).abs().cmple(bound).all(), "{}: {} against the exact mean {exact_mean}, quantisation {quantisation}", self.at, self.got);
    }

    /// Checks the pixel against the same exact mean within the fine positions' rounding: a
    /// crossing within 2^-12 of a pixel of its real position moves the area by at most half
    /// that (the triangle it sweeps is at most a pixel high), so a line's area by 2^-12; a
    /// corner's two lines, each through a neighbour's crossing too, move their meeting point
    /// by a few times that: 2^-10 — 1/64 of the quantised edge's bound (1/16) — and f32
    /// rounding.
    fn assert_exact(&self, exact: f32, inside: Vec3, outside: Vec3) {
        let exact_mean = inside * exact + outside * (1.0 - exact);
        let bound = (inside - outside).abs() * 2.0f32.powi(-10) + Vec3::splat(1e-6) * exact_mean.abs().max_element().max(1.0);
        assert!((self.got - exact_mean).abs().cmple(bound).all(), "{}: {} against the exact mean {exact_mean} (coverage {exact}; quantised edge's {})", self.at, self.got, self.area_a);
    }

    /// [`Self::assert_exact`] with the fine positions, [`Self::assert_within_quantisation`]
    /// without.
    fn assert_mean(&self, exact_mode: bool, exact: f32, inside: Vec3, outside: Vec3) {
        if exact_mode {
            self.assert_exact(exact, inside, outside);
        } else {
            self.assert_within_quantisation(exact, inside, outside);
        }
    }
}

/// The simple pixels of a two-colour reconstruction; without fine positions (`exact`
/// false) each checked to show the mix of both colours with its quantised edge's areas (its
/// secondary colour found).
fn simple_pixels(epi: &Epi, image: &[Vec3], trial: usize, colour_at: &impl Fn([f64; 2]) -> Vec3, exact: bool) -> Vec<Simple> {
    let w = epi.width() as usize;
    let mut out = Vec::new();
    for (i, px) in epi.pixels().iter().enumerate() {
        if !px.is_simple() {
            continue;
        }
        let (x, y) = (i % w, i / w);
        let at = format!("trial {trial}{}, pixel ({x},{y}), code {}", if exact { " (fine positions)" } else { "" }, px.code());
        let (ca, cb, area_a, extremes) = sides_of(PIXEL, px.code(), x, y, colour_at);
        assert_ne!(ca, cb, "{at}: the edge splits the pixel");
        let (got, want) = (image[i], ca * area_a as f32 + cb * (1.0 - area_a as f32));
        assert!(exact || (got - want).abs().max_element() <= 1e-5 * want.abs().max_element().max(1.0), "{at}: {got} against {want}");
        out.push(Simple { x, y, at, got, quantised: want, area_a, extremes });
    }
    out
}

#[test]
fn a_pixel_on_a_straight_edge_is_the_exact_area_weighted_mean() {
    let (w, h) = (48, 40);
    let (inside, outside) = (Vec3::new(17.0, 12.0, 4.0), Vec3::splat(0.02));
    let mut rng = Rng(7);
    for trial in 0..36 {
        // A line across the whole image, at any angle; `inside` on its side A. The last
        // third nearly horizontal or vertical (cornell's luminaire and boxes), whose
        // crossings keep one eighth along a run of pixels.
        let angle = if trial < 24 { rng.f64() * std::f64::consts::PI } else { (rng.f64() - 0.5) * 0.02 + (trial % 2) as f64 * std::f64::consts::FRAC_PI_2 };
        let centre = [8.0 + rng.f64() * (w as f64 - 16.0), 8.0 + rng.f64() * (h as f64 - 16.0)];
        let (dx, dy) = (angle.cos() * 100.0, angle.sin() * 100.0);
        let (p0, p1) = ([centre[0] - dx, centre[1] - dy], [centre[0] + dx, centre[1] + dy]);
        let colour_at = |r: [f64; 2]| if orient(p0, p1, r) > 0.0 { inside } else { outside };
        let points = points_coloured(w, h, &mut rng, colour_at, |_, _| false);
        // With the fine positions, and without them (within the quantisation).
        for exact in [true, false] {
            let (epi, image, antialiased) = reconstruct(w, h, &[(p0, p1)], &points, exact);
            let simple = simple_pixels(&epi, &image, trial, &colour_at, exact);
            for px in &simple {
                // The pixel's exact area on the line's `inside` side.
                let local = |r: [f64; 2]| [r[0] - px.x as f64, r[1] - px.y as f64];
                px.assert_mean(exact, side_a_area(local(p0), local(p1)) as f32, inside, outside);
            }
            if exact {
                // The fine positions matter: somewhere the quantised edge's mix is off by three
                // times the bound.
                let off = simple.iter().map(|px| (px.got - px.quantised).abs().max_element()).fold(0.0, f32::max);
                assert!(off > 0.05, "trial {trial}: {off}");
            }
            assert!(simple.len() >= w.min(h), "trial {trial}: {} simple pixels", simple.len());
            assert_eq!(antialiased as usize, simple.len(), "trial {trial}: every simple pixel took a secondary colour");
        }
    }
}

#[test]
fn a_pixel_holding_the_corner_of_a_bright_rectangle_takes_the_rectangle_as_its_secondary_colour_and_its_exact_area() {
    // The luminaire in the ceiling: a bright rectangle whose corners lie inside pixels (at
    // 0.2–0.8 of them). A corner pixel's crossings are on two adjacent sides (a simple pixel
    // whose quantised edge cuts the corner off as a triangle); no neighbour's centre lies in
    // that triangle, and where the rectangle holds less than half of the pixels beside the
    // corner (a quarter of the corners), their larger, primary region is outside, so only
    // their secondary regions continue it. With the fine positions and the segments' ends,
    // the corner pixel's outline is the two sides meeting inside it, and its mix exact.
    let (w, h) = (40, 32);
    let (inside, outside) = (Vec3::new(17.0, 12.0, 4.0), Vec3::splat(0.02));
    let mut rng = Rng(11);
    let mut corners_seen = 0;
    for trial in 0..32 {
        // Corners at 0.2–0.8 of their pixels.
        let place = |rng: &mut Rng, lo: f64, span: f64| lo + (rng.f64() * span).floor() + 0.2 + 0.6 * rng.f64();
        let (x0, x1) = (place(&mut rng, 6.0, 8.0), place(&mut rng, 22.0, 10.0));
        let (y0, y1) = (place(&mut rng, 5.0, 6.0), place(&mut rng, 18.0, 8.0));
        let colour_at = |r: [f64; 2]| if r[0] > x0 && r[0] < x1 && r[1] > y0 && r[1] < y1 { inside } else { outside };
        // The pixels holding a corner have no point: a straight edge cuts the corner off as a
        // triangle, so a point inside the rectangle may lie on the quantised edge's outer
        // side (and the reverse), and no colour is right for both. Their primary region is
        // then the larger one, coloured from the neighbours, as on `cornell` where the
        // luminaire's corner is a sixteenth of the pixel.
        let corner = |x: usize, y: usize| [x0, x1].iter().any(|&cx| cx.floor() as usize == x) && [y0, y1].iter().any(|&cy| cy.floor() as usize == y);
        let points = points_coloured(w, h, &mut rng, colour_at, corner);
        let segments = [([x0, y0], [x1, y0]), ([x1, y0], [x1, y1]), ([x1, y1], [x0, y1]), ([x0, y1], [x0, y0])];
        let overlap = |lo: f64, hi: f64, p: usize| (hi.min(p as f64 + 1.0) - lo.max(p as f64)).max(0.0);
        for exact in [true, false] {
            let (epi, image, antialiased) = reconstruct(w, h, &segments, &points, exact);
            let simple = simple_pixels(&epi, &image, trial, &colour_at, exact);
            for px in &simple {
                let area = (overlap(x0, x1, px.x) * overlap(y0, y1, px.y)) as f32;
                if exact {
                    // Corners too: the two sides meet inside the pixel.
                    corners_seen += usize::from(corner(px.x, px.y));
                    px.assert_exact(area, inside, outside);
                } else if corner(px.x, px.y) {
                    // The quantised edge cuts a triangle where the rectangle's corner is: the
                    // mean is not within the quantisation there, but both colours are in it.
                    corners_seen += 1;
                    assert!((px.got - outside).max_element() > 0.1 && (inside - px.got).min_element() > 0.1, "{}: {}", px.at, px.got);
                } else {
                    px.assert_within_quantisation(area, inside, outside);
                }
            }
            assert_eq!(antialiased as usize, simple.len(), "trial {trial}: every simple pixel took a secondary colour");
        }
    }
    assert!(corners_seen >= 2 * 32 * 3, "{corners_seen} simple corner pixels");
}

#[test]
fn the_closed_form_chord_area_equals_the_clipped_polygon() {
    let mut rng = Rng(3);
    let at = |side: u32, t: f32| match side {
        0 => [t, 0.0],
        1 => [1.0, t],
        2 => [t, 1.0],
        _ => [0.0, t],
    };
    for _ in 0..10_000 {
        let (sp, sq) = (rng.below(4) as u32, rng.below(4) as u32);
        if sp >= sq {
            continue;
        }
        let (p, q) = (at(sp, rng.unit()), at(sq, rng.unit()));
        let want = side_a_area([p[0] as f64, p[1] as f64], [q[0] as f64, q[1] as f64]);
        let got = super::chord_area_a(p, sp, q, sq);
        assert!((got as f64 - want).abs() < 1e-6, "{p:?} on {sp}, {q:?} on {sq}: {got} against {want}");
    }
}

/// `Epi::same_side_of_edge` against the line itself: in every simple pixel of a random line
/// across the image, random position pairs both clear of the line by twice the margin are
/// on one side exactly when the line says so, pairs nearer it never are, and no pixel the
/// line misses (edge-free) answers true. Without fine positions it answers false.
#[test]
fn positions_of_a_simple_pixel_are_on_one_side_of_its_edge_exactly_when_the_line_says_so() {
    let (w, h) = (40, 32);
    let mut rng = Rng(11);
    let mut agreed = 0;
    for trial in 0..24 {
        let angle = rng.f64() * std::f64::consts::PI;
        let centre = [8.0 + rng.f64() * (w as f64 - 16.0), 8.0 + rng.f64() * (h as f64 - 16.0)];
        let (dx, dy) = (angle.cos() * 100.0, angle.sin() * 100.0);
        let (p0, p1) = ([centre[0] - dx, centre[1] - dy], [centre[0] + dx, centre[1] + dy]);
        let points = points_coloured(w, h, &mut rng, |_| Vec3::ONE, |_, _| false);
        // Signed distance (pixels) of a position of pixel (x, y) from the line.
        let len = (p1[0] - p0[0]).hypot(p1[1] - p0[1]);
        let dist = |x: usize, y: usize, u: [f32; 2]| orient(p0, p1, [x as f64 + u[0] as f64, y as f64 + u[1] as f64]) / len;
        for exact in [true, false] {
            let (epi, _, _) = reconstruct(w, h, &[(p0, p1)], &points, exact);
            for y in 0..h {
                for x in 0..w {
                    let simple = epi.pixels[y * w + x].is_simple();
                    for _ in 0..16 {
                        let (a, b) = ([rng.unit(), rng.unit()], [rng.unit(), rng.unit()]);
                        let got = epi.same_side_of_edge(x, y, a, b);
                        let (da, db) = (dist(x, y, a), dist(x, y, b));
                        if !exact || !simple {
                            // Only the exact edge of a simple pixel decides; an edge-free
                            // pixel is the caller's case, not this one's.
                            assert!(!got, "trial {trial}: pixel ({x},{y}) simple {simple} exact {exact}");
                        } else if da.abs() > 2.0 * super::SIDE_MARGIN as f64 && db.abs() > 2.0 * super::SIDE_MARGIN as f64 {
                            assert_eq!(got, (da > 0.0) == (db > 0.0), "trial {trial}: pixel ({x},{y}) at {da} / {db} from the line");
                            agreed += 1;
                        } else if da.abs() < 0.5 * super::SIDE_MARGIN as f64 || db.abs() < 0.5 * super::SIDE_MARGIN as f64 {
                            assert!(!got, "trial {trial}: pixel ({x},{y}) at {da} / {db}: within the margin");
                        }
                    }
                }
            }
        }
    }
    assert!(agreed > 10_000, "{agreed} decided pairs");
}

/// The box-filtered mean of `colour_at` over pixel (x, y), on a 32 × 32 grid.
fn pixel_mean(x: usize, y: usize, colour_at: &impl Fn([f64; 2]) -> Vec3) -> Vec3 {
    let n = 32;
    let mut sum = Vec3::ZERO;
    for j in 0..n {
        for i in 0..n {
            sum += colour_at([x as f64 + (i as f64 + 0.5) / n as f64, y as f64 + (j as f64 + 0.5) / n as f64]);
        }
    }
    sum / (n * n) as f32
}

#[test]
fn a_strip_thinner_than_a_pixel_that_no_sample_reached_is_starved_until_samples_aimed_into_it_bring_it_back() {
    // A box's side seen edge-on: a bright strip 0.45–0.85 px wide between two parallel
    // edges, across the image at any angle, with a point in every pixel except where the
    // point would fall in the strip. The pixels the strip's edges cross show their primary
    // colour alone (nothing gives their secondary region, the strip, a colour): they are
    // starved, and every position `secondary_position` gives lies in the strip. With a
    // point there (a pick aimed into it), the strip comes back: the starved pixels become
    // few and the image nears the box-filtered one.
    let (w, h) = (40, 32);
    let (strip, outside) = (Vec3::new(9.0, 7.0, 3.0), Vec3::splat(0.05));
    let mut rng = Rng(23);
    for trial in 0..12 {
        let angle = 0.2 + rng.f64() * (std::f64::consts::PI - 0.4);
        let width = 0.45 + 0.4 * rng.f64();
        let centre = [12.0 + rng.f64() * (w as f64 - 24.0), 10.0 + rng.f64() * (h as f64 - 20.0)];
        let (dx, dy) = (angle.cos() * 100.0, angle.sin() * 100.0);
        let (nx, ny) = (-angle.sin() * 0.5 * width, angle.cos() * 0.5 * width);
        let line = |s: f64| ([centre[0] - dx + s * nx, centre[1] - dy + s * ny], [centre[0] + dx + s * nx, centre[1] + dy + s * ny]);
        let (l0, l1) = (line(-1.0), line(1.0));
        let in_strip = |r: [f64; 2]| (orient(l0.0, l0.1, r) > 0.0) != (orient(l1.0, l1.1, r) > 0.0);
        let colour_at = |r: [f64; 2]| if in_strip(r) { strip } else { outside };
        let mut points = points_coloured(w, h, &mut rng, colour_at, |_, _| false);
        for i in 0..w * h {
            let [u, v] = points.subpixel[i];
            if in_strip([(i % w) as f64 + u as f64, (i / w) as f64 + v as f64]) {
                (points.point[i], points.depth[i], points.age[i], points.color[i]) = (NO_POINT, f32::INFINITY, f32::INFINITY, Vec3::ZERO);
            }
        }
        let segments = [l0, l1];
        let error = |image: &[Vec3], epi: &Epi| -> f32 {
            (0..w * h).filter(|&i| epi.pixels()[i].is_simple()).map(|i| (image[i] - pixel_mean(i % w, i / w, &colour_at)).abs().max_element()).sum()
        };
        let (epi, image, _) = reconstruct(w, h, &segments, &points, true);
        let starved: Vec<(usize, usize)> = (0..w * h).filter(|&i| (epi.starved()[(i / w) * w.div_ceil(64) + (i % w) / 64] >> ((i % w) % 64)) & 1 == 1).map(|i| (i % w, i / w)).collect();
        assert!(starved.len() >= 3, "trial {trial}: {} starved pixels", starved.len());
        let before = error(&image, &epi);
        for &(x, y) in &starved {
            assert!(epi.pixels()[y * w + x].is_simple(), "trial {trial}: ({x},{y}) starved but not simple");
            for _ in 0..16 {
                let at = epi.secondary_position(x, y, rng.unit(), rng.unit()).unwrap_or_else(|| panic!("trial {trial}: ({x},{y}) starved without a position"));
                assert!(in_strip([x as f64 + at[0] as f64, y as f64 + at[1] as f64]), "trial {trial}: ({x},{y}) aimed at {at:?}, outside the strip");
            }
        }
        // Pixels not starved have no position.
        for i in (0..w * h).step_by(7) {
            if !starved.contains(&(i % w, i / w)) {
                assert_eq!(epi.secondary_position(i % w, i / w, 0.5, 0.5), None);
            }
        }
        // A sample at an aimed position in every starved pixel.
        for &(x, y) in &starved {
            let i = y * w + x;
            let at = epi.secondary_position(x, y, rng.unit(), rng.unit()).expect("starved");
            (points.point[i], points.depth[i], points.age[i], points.subpixel[i], points.color[i]) = (i as u32, 1.0, 1.0, at, strip);
        }
        let (epi_after, image_after, _) = reconstruct(w, h, &segments, &points, true);
        let left = epi_after.starved().iter().map(|b| b.count_ones()).sum::<u32>() as usize;
        let after = error(&image_after, &epi_after);
        assert!(left * 4 <= starved.len(), "trial {trial}: {left} of {} still starved", starved.len());
        assert!(after < 0.5 * before, "trial {trial}: error over the simple pixels {before} → {after}");
    }
}
