//! Receivers wholly in umbra behind one flat occluder (issue 15's "cull receivers wholly in
//! umbra"): a blocker triangle, or the convex quadrilateral it makes with a coplanar
//! neighbour across an edge (a wall's face), whose plane separates the light (above the
//! receiver's plane) from the receiver and which holds every point where a line from a light
//! corner to a receiver corner crosses that plane. Every line from the light to the receiver
//! lies in the convex hull of the two polygons, whose section by the plane is the convex hull
//! of those crossings, so the occluder meets every line: the receiver sees none of the light.
//! Such receivers get one face in umbra and no segments, without tracing any surface (the
//! lights of the other rooms, seen through a wall).
use super::geometry::{edge_key, Geometry};
use glam::DVec3;

/// The crossings of the lines from every light corner to every receiver corner with the
/// plane `(n, d)` (`n · x = d`), or `None` when the plane does not strictly separate them.
fn crossings(light: &[DVec3], receiver: &[DVec3; 3], n: DVec3, d: f64, tol: f64) -> Option<Vec<DVec3>> {
    let hl: Vec<f64> = light.iter().map(|p| n.dot(*p) - d).collect();
    let hr = receiver.map(|p| n.dot(p) - d);
    let apart = |s: f64| hl.iter().all(|h| s * h > tol) && hr.iter().all(|h| s * h < -tol);
    if !apart(1.0) && !apart(-1.0) {
        return None;
    }
    let mut out = Vec::with_capacity(light.len() * 3);
    for (l, a) in light.iter().zip(&hl) {
        for (r, b) in receiver.iter().zip(&hr) {
            out.push(*l + (*r - *l) * (a / (a - b)));
        }
    }
    Some(out)
}

/// Whether `p` (in the polygon's plane, normal `n`) lies inside the convex polygon `poly`
/// (either winding), `tol` inside its sides.
fn inside_convex(poly: &[DVec3], n: DVec3, p: DVec3, tol: f64) -> bool {
    let k = poly.len();
    let s: Vec<f64> = (0..k)
        .map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % k]);
            let e = (b - a).normalize_or_zero();
            e.cross(p - a).dot(n)
        })
        .collect();
    s.iter().all(|x| *x > tol) || s.iter().all(|x| *x < -tol)
}

/// Whether the quadrilateral `poly` (corners in order, normal `n`) is convex.
fn convex(poly: &[DVec3; 4], n: DVec3) -> bool {
    let s: Vec<f64> = (0..4).map(|i| (poly[(i + 1) % 4] - poly[i]).cross(poly[(i + 2) % 4] - poly[(i + 1) % 4]).dot(n)).collect();
    s.iter().all(|x| *x > 0.0) || s.iter().all(|x| *x < 0.0)
}

/// The occluder that hides all of `light` (clipped above the receiver) from the receiver
/// triangle `receiver`, among `blockers`: its triangle ids (one or two), if any.
pub fn covering_occluder(g: &Geometry, light: &[DVec3], receiver: &[DVec3; 3], blockers: &[u32], tol: f64) -> Option<Vec<u32>> {
    for &t in blockers {
        let [a, b, c] = g.tri(t);
        let Some(n) = (b - a).cross(c - a).try_normalize() else { continue };
        let Some(x) = crossings(light, receiver, n, n.dot(a), tol) else { continue };
        if x.iter().all(|p| inside_convex(&[a, b, c], n, *p, tol)) {
            return Some(vec![t]);
        }
        // With a coplanar neighbour across one of its edges, as a convex quadrilateral.
        let v = g.tris[t as usize];
        for k in 0..3 {
            let (i, j, o) = (v[k], v[(k + 1) % 3], v[(k + 2) % 3]);
            let Some(around) = g.edge_tris.get(&edge_key(i, j)) else { continue };
            for &u in around {
                if u == t {
                    continue;
                }
                let Some(&w) = g.tris[u as usize].iter().find(|x| **x != i && **x != j) else { continue };
                let wp = g.pos[w as usize];
                if n.dot(wp - a).abs() > tol {
                    continue;
                }
                let quad = [g.pos[o as usize], g.pos[i as usize], wp, g.pos[j as usize]];
                if convex(&quad, n) && x.iter().all(|p| inside_convex(&quad, n, *p, tol)) {
                    return Some(vec![t, u]);
                }
            }
        }
    }
    None
}
