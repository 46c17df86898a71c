//! The planar arrangement of a receiver's discontinuity segments (paper 002 §2: "the
//! discontinuity mesh … a winged-edge structure" whose faces carry backprojections): the
//! segments and the triangle's sides split at every crossing and at every end lying on
//! another segment, ends closer than the tolerance snapped to one vertex, in a half-edge
//! structure whose faces are the cycles of `next`, with floating components (a shadow
//! wholly inside the triangle) attached as holes to the face around them.
//!
//! In f64 with a length tolerance: near-coincident points become one vertex, collinear
//! overlapping segments share their edges, and a segment end within the tolerance of
//! another segment is put on it.
use super::fast_hash::FastMap;
use super::segments::{Generator, Segment};
use glam::DVec2;

#[derive(Debug, Clone, Default)]
pub struct Arrangement {
    pub vertices: Vec<DVec2>,
    /// Undirected edges (vertex ids) with the generator of the segment they come from
    /// (`None` for the triangle's sides).
    pub edges: Vec<([u32; 2], Option<Generator>)>,
    /// Half-edge `2e` runs along edge `e`, `2e + 1` against it; `next[h]` follows the face on
    /// its left.
    pub next: Vec<u32>,
    /// The bounded faces: the outer cycle (a half-edge on it) and the hole cycles.
    pub faces: Vec<FaceCycles>,
    /// Connected components of the edge graph.
    pub components: usize,
}

#[derive(Debug, Clone, Default)]
pub struct FaceCycles {
    pub outer: u32,
    pub holes: Vec<u32>,
    /// Twice the outer cycle's area.
    pub area2: f64,
}

impl Arrangement {
    #[inline]
    pub fn origin(&self, h: u32) -> u32 {
        let e = &self.edges[(h / 2) as usize].0;
        if h.is_multiple_of(2) {
            e[0]
        } else {
            e[1]
        }
    }

    /// The half-edges of the cycle through `h`.
    pub fn cycle(&self, h: u32) -> impl Iterator<Item = u32> + '_ {
        let mut at = Some(h);
        std::iter::from_fn(move || {
            let cur = at?;
            let n = self.next[cur as usize];
            at = (n != h).then_some(n);
            Some(cur)
        })
    }

    /// Every half-edge bounding face `f` (outer cycle and holes).
    pub fn face_half_edges(&self, f: usize) -> Vec<u32> {
        let face = &self.faces[f];
        let mut out: Vec<u32> = self.cycle(face.outer).collect();
        for h in &face.holes {
            out.extend(self.cycle(*h));
        }
        out
    }

    /// Whether `q` is inside face `f` (even–odd over its half-edges: an edge with the face on
    /// both sides counts twice and so not at all).
    pub fn face_contains(&self, f: usize, q: DVec2) -> bool {
        let mut inside = false;
        for h in self.face_half_edges(f) {
            let (a, b) = (self.vertices[self.origin(h) as usize], self.vertices[self.origin(h ^ 1) as usize]);
            if (a.y > q.y) != (b.y > q.y) && q.x < a.x + (b.x - a.x) * (q.y - a.y) / (b.y - a.y) {
                inside = !inside;
            }
        }
        inside
    }

    /// A point strictly inside face `f`: on the horizontal line through the middle of the
    /// widest gap between its vertices' heights, the middle of the widest inside interval.
    pub fn interior_point(&self, f: usize) -> DVec2 {
        let hs = self.face_half_edges(f);
        let mut ys: Vec<f64> = hs.iter().map(|h| self.vertices[self.origin(*h) as usize].y).collect();
        ys.sort_by(f64::total_cmp);
        ys.dedup();
        let mut y = ys[0];
        let mut gap = -1.0;
        for w in ys.windows(2) {
            if w[1] - w[0] > gap {
                gap = w[1] - w[0];
                y = 0.5 * (w[0] + w[1]);
            }
        }
        let mut xs: Vec<f64> = hs
            .iter()
            .filter_map(|h| {
                let (a, b) = (self.vertices[self.origin(*h) as usize], self.vertices[self.origin(*h ^ 1) as usize]);
                ((a.y > y) != (b.y > y)).then(|| a.x + (b.x - a.x) * (y - a.y) / (b.y - a.y))
            })
            .collect();
        xs.sort_by(f64::total_cmp);
        let mut best = (xs.first().copied().unwrap_or(0.0), xs.get(1).copied().unwrap_or(0.0));
        for p in xs.chunks(2) {
            if p.len() == 2 && p[1] - p[0] > best.1 - best.0 {
                best = (p[0], p[1]);
            }
        }
        DVec2::new(0.5 * (best.0 + best.1), y)
    }

    /// Distance from `q` to the nearest edge of face `f`.
    pub fn distance_to_boundary(&self, f: usize, q: DVec2) -> f64 {
        self.face_half_edges(f)
            .iter()
            .map(|h| {
                let (a, b) = (self.vertices[self.origin(*h) as usize], self.vertices[self.origin(*h ^ 1) as usize]);
                let t = ((q - a).dot(b - a) / (b - a).length_squared().max(1e-300)).clamp(0.0, 1.0);
                q.distance(a + (b - a) * t)
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// Bytes held (for the benchmark's memory figure).
    pub fn bytes(&self) -> usize {
        self.vertices.len() * 16 + self.edges.len() * 24 + self.next.len() * 4 + self.faces.iter().map(|f| 40 + f.holes.len() * 4).sum::<usize>()
    }
}

/// Snaps points closer than the tolerance to one vertex (a hash of cells twice the
/// tolerance; the neighbouring cells within the tolerance are searched too).
struct Snap {
    cell: f64,
    tol: f64,
    tol2: f64,
    /// Per cell its first and last vertex; `next` chains each cell's vertices in the order
    /// they came (no list allocated per cell).
    map: FastMap<(i64, i64), (u32, u32)>,
    next: Vec<u32>,
    vertices: Vec<DVec2>,
}

impl Snap {
    fn id(&mut self, p: DVec2) -> u32 {
        let c = |x: f64| (x / self.cell).floor() as i64;
        let (cx, cy) = (c(p.x), c(p.y));
        // Only the cells a point within the tolerance (grown by 1 %, above the rounding) can
        // lie in: one or two of the three each way, in the order of the 3 × 3 search they
        // replace (the same vertex found first).
        let r = 1.01 * self.tol;
        let (x0, x1) = (c(p.x - r).max(cx - 1), c(p.x + r).min(cx + 1));
        let (y0, y1) = (c(p.y - r).max(cy - 1), c(p.y + r).min(cy + 1));
        for x in x0..=x1 {
            for y in y0..=y1 {
                let mut at = self.map.get(&(x, y)).map_or(u32::MAX, |c| c.0);
                while at != u32::MAX {
                    if self.vertices[at as usize].distance_squared(p) <= self.tol2 {
                        return at;
                    }
                    at = self.next[at as usize];
                }
            }
        }
        let v = self.vertices.len() as u32;
        self.vertices.push(p);
        self.next.push(u32::MAX);
        match self.map.entry((cx, cy)) {
            std::collections::hash_map::Entry::Occupied(mut c) => {
                self.next[c.get().1 as usize] = v;
                c.get_mut().1 = v;
            }
            std::collections::hash_map::Entry::Vacant(c) => {
                c.insert((v, v));
            }
        }
        v
    }
}

/// The arrangement of `segments` inside the triangle `corners` (counter-clockwise).
pub fn build(corners: &[DVec2; 3], segments: &[Segment], tol: f64) -> Arrangement {
    let mut items: Vec<(DVec2, DVec2, Option<Generator>)> = (0..3).map(|k| (corners[k], corners[(k + 1) % 3], None)).collect();
    items.extend(segments.iter().map(|s| (s.a, s.b, Some(s.generator))));
    let n = items.len();
    // Split parameters (item, parameter): each item's ends, crossings, and other items'
    // ends lying on it; in one list, sorted by item then parameter below.
    let mut splits: Vec<(u32, f64)> = (0..n as u32).flat_map(|i| [(i, 0.0), (i, 1.0)]).collect();
    let boxes: Vec<(DVec2, DVec2)> = items.iter().map(|(a, b, _)| (a.min(*b) - tol, a.max(*b) + tol)).collect();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|i, j| boxes[*i].0.x.total_cmp(&boxes[*j].0.x));
    for (oi, &i) in order.iter().enumerate() {
        for &j in &order[oi + 1..] {
            if boxes[j].0.x > boxes[i].1.x {
                break;
            }
            if boxes[j].0.y > boxes[i].1.y || boxes[j].1.y < boxes[i].0.y {
                continue;
            }
            let (a, b, _) = items[i];
            let (c, d, _) = items[j];
            let (r, s) = (b - a, d - c);
            let den = r.perp_dot(s);
            if den.abs() > 1e-300 {
                let t = (c - a).perp_dot(s) / den;
                let u = (c - a).perp_dot(r) / den;
                let (ti, uj) = (tol / r.length(), tol / s.length());
                if t > -ti && t < 1.0 + ti && u > -uj && u < 1.0 + uj {
                    splits.push((i as u32, t.clamp(0.0, 1.0)));
                    splits.push((j as u32, u.clamp(0.0, 1.0)));
                }
            }
            // Ends of each on the other (collinear overlaps, T-junctions within tolerance).
            for (k, p) in [(i, c), (i, d), (j, a), (j, b)] {
                let (e0, e1, _) = items[k];
                let e = e1 - e0;
                let t = (p - e0).dot(e) / e.length_squared();
                if (-1e-12..=1.0 + 1e-12).contains(&t) && (e0 + e * t).distance(p) <= tol {
                    splits.push((k as u32, t.clamp(0.0, 1.0)));
                }
            }
        }
    }
    let mut snap = Snap { cell: 2.0 * tol, tol, tol2: tol * tol, map: FastMap::default(), next: Vec::new(), vertices: Vec::new() };
    let mut edge_ids: FastMap<(u32, u32), u32> = FastMap::default();
    let mut edges: Vec<([u32; 2], Option<Generator>)> = Vec::new();
    splits.sort_unstable_by(|x, y| x.0.cmp(&y.0).then(x.1.total_cmp(&y.1)));
    for sp in splits.chunk_by(|x, y| x.0 == y.0) {
        let (a, b, gen) = &items[sp[0].0 as usize];
        let mut prev: Option<u32> = None;
        for &(_, t) in sp {
            let v = snap.id(a.lerp(*b, t));
            if let Some(p) = prev {
                if p != v {
                    let key = (p.min(v), p.max(v));
                    edge_ids.entry(key).or_insert_with(|| {
                        edges.push(([p, v], *gen));
                        (edges.len() - 1) as u32
                    });
                }
            }
            prev = Some(v);
        }
    }
    let vertices = snap.vertices;
    half_edges(vertices, edges)
}

/// The half-edge structure, its cycles as faces and holes, and the components.
fn half_edges(vertices: Vec<DVec2>, edges: Vec<([u32; 2], Option<Generator>)>) -> Arrangement {
    let nv = vertices.len();
    let mut out_of: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for (e, (v, _)) in edges.iter().enumerate() {
        out_of[v[0] as usize].push(2 * e as u32);
        out_of[v[1] as usize].push(2 * e as u32 + 1);
    }
    let mut arr = Arrangement { vertices, edges, next: Vec::new(), faces: Vec::new(), components: 0 };
    let dir = |arr: &Arrangement, h: u32| arr.vertices[arr.origin(h ^ 1) as usize] - arr.vertices[arr.origin(h) as usize];
    // Position of each half-edge in its origin's counter-clockwise order (each angle once).
    let angle: Vec<f64> = (0..arr.edges.len() as u32 * 2).map(|h| {
        let d = dir(&arr, h);
        d.y.atan2(d.x)
    }).collect();
    let mut slot = vec![0u32; arr.edges.len() * 2];
    for list in out_of.iter_mut() {
        list.sort_by(|a, b| angle[*a as usize].total_cmp(&angle[*b as usize]));
        for (k, h) in list.iter().enumerate() {
            slot[*h as usize] = k as u32;
        }
    }
    // The face on the left of u→v continues with the edge out of v next clockwise from v→u.
    arr.next = (0..arr.edges.len() as u32 * 2)
        .map(|h| {
            let twin = h ^ 1;
            let list = &out_of[arr.origin(twin) as usize];
            let k = slot[twin as usize] as usize;
            list[(k + list.len() - 1) % list.len()]
        })
        .collect();
    // Components (union–find over edges).
    let mut parent: Vec<u32> = (0..nv as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    for (v, _) in &arr.edges {
        let (a, b) = (find(&mut parent, v[0]), find(&mut parent, v[1]));
        parent[a as usize] = b;
    }
    let used: Vec<bool> = (0..nv).map(|v| !out_of[v].is_empty()).collect();
    let comp: Vec<u32> = (0..nv as u32).map(|v| find(&mut parent, v)).collect();
    arr.components = (0..nv).filter(|v| used[*v] && comp[*v] == *v as u32).count();
    // Cycles and their signed areas.
    let mut seen = vec![false; arr.next.len()];
    let (mut pos, mut neg) = (Vec::new(), Vec::new());
    for h in 0..arr.next.len() as u32 {
        if seen[h as usize] {
            continue;
        }
        // Relative to the cycle's first corner, so that an edge walked both ways (a tree, a
        // dangling segment) cancels to rounding, which the threshold tells from an area.
        let (mut a2, mut mag) = (0.0, 0.0);
        let o = arr.vertices[arr.origin(h) as usize];
        for x in arr.cycle(h).collect::<Vec<_>>() {
            seen[x as usize] = true;
            let (p, q) = (arr.vertices[arr.origin(x) as usize] - o, arr.vertices[arr.origin(x ^ 1) as usize] - o);
            a2 += p.perp_dot(q);
            mag += p.perp_dot(q).abs();
        }
        if a2 > 1e-12 * mag {
            pos.push((h, a2));
        } else {
            neg.push(h);
        }
    }
    arr.faces = pos.iter().map(|(h, a2)| FaceCycles { outer: *h, holes: Vec::new(), area2: *a2 }).collect();
    // Each outer boundary of a component goes into the smallest face of another component
    // around it; none around it: the unbounded face.
    let bbox: Vec<(DVec2, DVec2)> = arr
        .faces
        .iter()
        .map(|f| arr.cycle(f.outer).map(|x| arr.vertices[arr.origin(x) as usize]).fold((DVec2::INFINITY, DVec2::NEG_INFINITY), |(lo, hi), p| (lo.min(p), hi.max(p))))
        .collect();
    for h in neg {
        let v = arr.origin(h);
        let q = arr.vertices[v as usize];
        let mut best: Option<(usize, f64)> = None;
        for (f, face) in arr.faces.iter().enumerate() {
            if comp[arr.origin(face.outer) as usize] == comp[v as usize] || q.cmplt(bbox[f].0).any() || q.cmpgt(bbox[f].1).any() {
                continue;
            }
            if best.is_some_and(|(_, a)| a <= face.area2) {
                continue;
            }
            let mut inside = false;
            for x in arr.cycle(face.outer) {
                let (a, b) = (arr.vertices[arr.origin(x) as usize], arr.vertices[arr.origin(x ^ 1) as usize]);
                if (a.y > q.y) != (b.y > q.y) && q.x < a.x + (b.x - a.x) * (q.y - a.y) / (b.y - a.y) {
                    inside = !inside;
                }
            }
            if inside {
                best = Some((f, face.area2));
            }
        }
        if let Some((f, _)) = best {
            arr.faces[f].holes.push(h);
        }
    }
    arr
}
