//! The irradiance cache of the `gi` shader (paper 000 §7: "a dynamic variant of irradiance
//! caching [Ward et al. 1988] modified for interactive use"), one per loaded scene on each
//! worker.
//!
//! A record holds the irradiance E of the diffuse indirect term at a point (everything that
//! arrives except the lights' own emission, which next-event estimation handles), gathered
//! from M × N stratified cosine-weighted hemisphere rays, with Ward & Heckbert's (1992)
//! rotation and translation gradients and the harmonic mean distance R of the hits. A point
//! p with normal n is served by the records of Ward's weight
//! w = 1 / (|p − pᵢ| / Rᵢ + √(1 − n·nᵢ)) above 1/a, each extrapolated with its gradients,
//! Eᵢ + (nᵢ × n)·∇r + (p − pᵢ)·∇t, and averaged by weight; records "in front" of p are
//! skipped (Ward's test). R is clamped to [Rmax / 16, Rmax] with Rmax = cell / a, so a
//! record serves no farther than one grid cell and a lookup visits the 27 cells around it
//! (skipping those a whole cell away: no record there can reach it); and to
//! E / |∇t E| (Křivánek et al. 2006's gradient limit), so extrapolation stays positive;
//! where that limit falls below Rmin the gradients are scaled down instead
//! ([`limit_gradients`]), so no lookup moves a record's irradiance by more than a·E per gradient.
//!
//! Refinement: a record keeps the mean of its gathers (before R's clamp and the gradient
//! bounds). Each lookup counts against the record of the highest weight; once a record has
//! served a quarter as many lookups as it holds rays ([`REFINE_USES_PER_RAYS`]), the lookup
//! asks for `rays` more
//! ([`IrradianceCache::lookup_counted`]), and the merged gathers replace the record's values
//! ([`IrradianceCache::refine`]), up to the settings' `max_rays`. So records grow in
//! proportion to their use — a still view's records lose their noise as its samples
//! accumulate (the irradiance no longer freezes at one gather's noise, which set the plateau
//! of a still `gi` image) — and a record that serves few lookups costs no more than before.
//! A gather costs about `rays` paths, so refinement adds at most four paths per lookup while
//! a record grows (the total is fixed by `max_rays`; the quarter makes it early: measured
//! against asking after as many lookups as rays and after an eighth, `README` *Converging at
//! rest*).
//!
//! Lookups are most of a worker's time with `gi` once the records exist (31–36 % of a
//! worker's profile at rest before this layout), so the grid keeps, next to each other in
//! its cell, what the weight test reads of each record ([`Entry`]: position, normal, R), and
//! reads a record itself only when it serves; cells are found by a multiply-and-shift hash
//! of the packed cell coordinates ([`CellHasher`]) rather than the standard SipHash.
//!
//! Bounded memory: at most [`MAX_RECORDS`] records in a ring (the oldest is dropped), a
//! number of this module, never one an input gives.
//!
//! Validity: records are valid while the scene is unchanged. When a batch's transforms
//! differ from the ones the cache was built with, [`IrradianceCache::sync`] drops every
//! record on a moved object and every record whose hemisphere sees a moved object's old or
//! new world bounds — any corner of the box above the record's tangent plane, ignoring
//! occlusion (conservative: a record the object could have shadowed or lit is never kept).
//! Other records stay. Changing the shader's cache parameters empties the cache. A batch
//! that started under older transforms neither reads nor writes records (it computes its
//! irradiance without storing it), so no record mixes two object placements.
use crate::rng::Rng;
use edgepoint_scene::geometry::{box_corners, transformed_box};
use edgepoint_scene::material::Frame;
use edgepoint_scene::Scene;
use glam::{Affine3A, Vec3};
use std::collections::HashMap;
use std::f32::consts::{PI, TAU};
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::RwLock;

/// The most records a cache holds (each about 250 bytes with its gathers for refinement and
/// its grid entry: ~16 MB).
pub const MAX_RECORDS: usize = 1 << 16;
/// A record asks for refinement after serving its rays / this many lookups (module docs).
const REFINE_USES_PER_RAYS: u32 = 4;
/// Grid cells across the scene's bounding-box diagonal.
const CELLS_ACROSS: f32 = 32.0;
/// Rmin = Rmax / this.
const R_RANGE: f32 = 16.0;

/// What records depend on besides the scene: the shader parameters they were made with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CacheSettings {
    /// Ward's accuracy a.
    pub error: f32,
    /// Hemisphere rays per record.
    pub rays: u32,
    /// The path depth behind each hemisphere ray.
    pub max_depth: u32,
    /// Hemisphere rays a record grows to by refinement (module docs; at most `rays`: none).
    pub max_rays: u32,
}

/// A batch's permission to use the cache: valid while the cache is at `version`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ticket {
    version: u64,
    settings: CacheSettings,
}

/// One irradiance record. Gradients are per colour channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Record {
    pub p: Vec3,
    pub n: Vec3,
    pub e: Vec3,
    /// Harmonic mean distance, clamped.
    pub r: f32,
    pub grad_r: [Vec3; 3],
    pub grad_t: [Vec3; 3],
    /// The object the record lies on.
    pub object: u32,
    /// Hemisphere rays gathered into it (`rays` of the settings, more once refined).
    pub rays: u32,
}

impl Record {
    /// The record's irradiance extrapolated to (p, n) with its gradients, never negative.
    #[inline]
    pub fn extrapolate(&self, p: Vec3, n: Vec3) -> Vec3 {
        let rot = self.n.cross(n);
        let d = p - self.p;
        let c = |i: usize| self.e[i] + rot.dot(self.grad_r[i]) + d.dot(self.grad_t[i]);
        Vec3::new(c(0), c(1), c(2)).max(Vec3::ZERO)
    }

    /// Ward's weight of this record at (p, n) (capped, so a lookup at the record itself is finite).
    #[inline]
    pub fn weight(&self, p: Vec3, n: Vec3) -> f32 {
        ward_weight(self.p, self.n, self.r, p, n)
    }
}

/// Ward's weight at (p, n) of a record at (rp, rn) with harmonic mean distance r.
#[inline]
fn ward_weight(rp: Vec3, rn: Vec3, r: f32, p: Vec3, n: Vec3) -> f32 {
    let den = (p - rp).length() / r + (1.0 - n.dot(rn)).max(0.0).sqrt();
    1.0 / den.max(1e-6)
}

/// A record in its grid cell: what a lookup's weight test reads (32 bytes, the cell's
/// records side by side), and where the record is.
#[derive(Debug, Clone, Copy)]
struct Entry {
    p: Vec3,
    n: Vec3,
    r: f32,
    index: u32,
}

/// Hashes a packed cell key (one `u64`) with SplitMix64's finaliser: every bit of the key
/// reaches the high bits the table's control bytes take and the low bits its buckets take.
#[derive(Default)]
struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(self.0 ^ u64::from(b));
        }
    }
    fn write_u64(&mut self, x: u64) {
        let mut z = x ^ self.0.rotate_left(17);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        self.0 = z ^ (z >> 31);
    }
}

type Grid = HashMap<u64, Vec<Entry>, BuildHasherDefault<CellHasher>>;

/// Cell coordinates clamped to ±2^20 packed into 21 bits each.
#[inline]
fn pack(c: [i32; 3]) -> u64 {
    let f = |v: i32| (v.clamp(-(1 << 20), (1 << 20) - 1) as u64) & 0x1f_ffff;
    (f(c[0]) << 42) | (f(c[1]) << 21) | f(c[2])
}

/// A hemisphere gathered for a record (before R's clamping).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gathered {
    pub e: Vec3,
    /// Harmonic mean hit distance (infinite when every ray escaped).
    pub r: f32,
    pub grad_r: [Vec3; 3],
    pub grad_t: [Vec3; 3],
}

/// Strata (M, N) for `rays` hemisphere rays: N ≈ π M, as Ward and Heckbert advise.
pub fn strata(rays: u32) -> (usize, usize) {
    let m = ((rays as f32 / PI).sqrt().round() as usize).max(2);
    (m, (rays as usize / m).max(3))
}

/// Gathers the hemisphere around `frame.n` with M × N stratified cosine-weighted rays (θ_j =
/// asin √((j + ξ)/M), φ_k = 2π (k + ξ')/N); `trace(direction)` gives the radiance arriving
/// from that direction and the distance to what it hit (infinite for an escaped ray).
/// Gradients: Ward & Heckbert 1992, in the form of Křivánek et al.'s course notes:
/// ∇r E = π/(MN) Σ_k v_k Σ_j tan θ_j L_jk (the sign that goes with Eᵢ + (nᵢ × n)·∇r, as
/// the half-plane test derives: the published −tan θ pairs with n × nᵢ), and
/// ∇t E = Σ_k [ u_k 2π/N Σ_{j≥1} sin θ_j− cos² θ_j− / min(R_jk, R_j−1,k) (L_jk − L_j−1,k)
///            + v_k− Σ_j (sin θ_j+ − sin θ_j−) / min(R_jk, R_j,k−1) (L_jk − L_j,k−1) ],
/// θ_j− = asin √(j/M), θ_j+ = asin √((j+1)/M), u_k the base-plane direction φ_k and v_k−
/// the one at φ_k− + π/2 = 2πk/N + π/2.
pub fn gather(frame: &Frame, rays: u32, rng: &mut Rng, mut trace: impl FnMut(Vec3) -> (Vec3, f32)) -> Gathered {
    let (m, n) = strata(rays);
    let mut l = vec![Vec3::ZERO; m * n];
    let mut r = vec![0f32; m * n];
    let mut sum = Vec3::ZERO;
    let mut inv_r = 0.0f64;
    let mut grad_r = [Vec3::ZERO; 3];
    let tangent = |phi: f32| frame.to_world(Vec3::new(phi.cos(), phi.sin(), 0.0));
    for k in 0..n {
        for j in 0..m {
            let sin2 = (j as f32 + rng.next_f32()) / m as f32;
            let (sin_t, cos_t) = (sin2.sqrt(), (1.0 - sin2).max(0.0).sqrt());
            let phi = TAU * (k as f32 + rng.next_f32()) / n as f32;
            let dir = frame.to_world(Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t));
            let (li, ri) = trace(dir);
            let (li, ri) = if li.is_finite() { (li, ri) } else { (Vec3::ZERO, ri) };
            l[j * n + k] = li;
            r[j * n + k] = ri;
            sum += li;
            if ri.is_finite() && ri > 0.0 {
                inv_r += 1.0 / ri as f64;
            }
            // v_k for the rotation gradient: the base-plane direction a quarter turn on
            // (∇r = ∫ L (n × ω) dω = ∫ L sin θ v dω).
            let v = tangent(phi + PI / 2.0) * (sin_t / cos_t.max(1e-4));
            for (c, g) in grad_r.iter_mut().enumerate() {
                *g += v * li[c];
            }
        }
    }
    let scale = PI / (m * n) as f32;
    let mut grad_t = [Vec3::ZERO; 3];
    let idx = |j: usize, k: usize| j * n + k;
    for k in 0..n {
        let u = tangent(TAU * (k as f32 + 0.5) / n as f32) * (TAU / n as f32);
        let v = tangent(TAU * k as f32 / n as f32 + PI / 2.0);
        let km = (k + n - 1) % n;
        for j in 0..m {
            let s_minus = (j as f32 / m as f32).sqrt();
            if j >= 1 {
                let cos2 = 1.0 - j as f32 / m as f32;
                let c = s_minus * cos2 / r[idx(j, k)].min(r[idx(j - 1, k)]);
                let dl = l[idx(j, k)] - l[idx(j - 1, k)];
                for (ch, g) in grad_t.iter_mut().enumerate() {
                    *g += u * (c * dl[ch]);
                }
            }
            let s_plus = ((j + 1) as f32 / m as f32).sqrt();
            let c = (s_plus - s_minus) / r[idx(j, k)].min(r[idx(j, km)]);
            let dl = l[idx(j, k)] - l[idx(j, km)];
            for (ch, g) in grad_t.iter_mut().enumerate() {
                *g += v * (c * dl[ch]);
            }
        }
    }
    let r_harm = if inv_r > 0.0 { ((m * n) as f64 / inv_r) as f32 } else { f32::INFINITY };
    Gathered { e: sum * scale, r: r_harm, grad_r: grad_r.map(|g| g * scale), grad_t }
}

/// Bounds each channel's gradients so that a lookup the record serves (distance d < a·R,
/// and √(1 − n·nᵢ) < a, so |nᵢ × n| < √2·a) moves its irradiance by at most a·Eᵢ per
/// gradient: |∇t| ≤ Eᵢ / R and |∇r| ≤ Eᵢ / √2, a gradient above its bound scaled down to it.
///
/// Why: the translation bound is Křivánek et al.'s R ≤ E / |∇t E|, which `insert` applies
/// to R — but R is then raised to Rmin, and where a record's hemisphere rays hit a wall at
/// almost no distance (a crease, the foot of a box) the estimated ∇t is so large that
/// E / |∇t| lies far below Rmin; extrapolating such a gradient over a·Rmin made pixels 100×
/// too bright (fireflies of 3–13 where the floor is 0.1, seen along `cornell`'s creases).
/// The rotation estimate weights each ray by tan θ, unbounded at the horizon, so one grazing
/// ray can make it as large.
fn limit_gradients(e: Vec3, r: f32, grad_r: [Vec3; 3], grad_t: [Vec3; 3]) -> ([Vec3; 3], [Vec3; 3]) {
    let limit = |g: Vec3, bound: f32| {
        let len = g.length();
        if len > bound && len > 0.0 {
            g * (bound.max(0.0) / len)
        } else {
            g
        }
    };
    let mut out = (grad_r, grad_t);
    for c in 0..3 {
        out.0[c] = limit(grad_r[c], e[c] / std::f32::consts::SQRT_2);
        out.1[c] = limit(grad_t[c], e[c] / r);
    }
    out
}

/// Keeps the items of `v` whose `keep` is true (the same index).
fn retain_where<T>(v: &mut Vec<T>, keep: &[bool]) {
    let mut k = keep.iter();
    v.retain(|_| *k.next().unwrap_or(&false));
}

struct State {
    settings: Option<CacheSettings>,
    /// The object placements the records were made under (empty: none yet).
    transforms: Vec<Affine3A>,
    version: u64,
    records: Vec<Record>,
    /// Per record (same index): the mean of its gathers before R's clamp and the gradient
    /// bounds, and the face's normal they were gathered over (what refinement adds to).
    raw: Vec<Raw>,
    /// Per record: lookups it served best since it was made or last refined.
    uses: Vec<AtomicU32>,
    /// Ring position of the next record once `records` is full.
    next: usize,
    grid: Grid,
}

impl State {
    /// Adds record `i` (already in `records`) to its cell.
    fn link(&mut self, key: u64, i: usize) {
        let r = &self.records[i];
        self.grid.entry(key).or_default().push(Entry { p: r.p, n: r.n, r: r.r, index: i as u32 });
    }
}

/// A record's gathers, merged (see [`Raw::merge`]), and the face's normal at its point.
#[derive(Debug, Clone, Copy)]
struct Raw {
    g: Gathered,
    ng: Vec3,
}

impl Raw {
    /// The mean of two gathers weighted by their rays (the harmonic mean distance through
    /// its inverse): an estimate of the same irradiance, gradients and distance with the
    /// noise of all their rays (each gather stratifies the whole hemisphere).
    fn merge(&mut self, rays: u32, g: &Gathered, more: u32) {
        let (w0, w1) = (rays as f32 / (rays + more) as f32, more as f32 / (rays + more) as f32);
        let a = &mut self.g;
        a.e = a.e * w0 + g.e * w1;
        let inv = |r: f32| if r.is_finite() && r > 0.0 { 1.0 / r } else { 0.0 };
        let inv_r = inv(a.r) * w0 + inv(g.r) * w1;
        a.r = if inv_r > 0.0 { 1.0 / inv_r } else { f32::INFINITY };
        for c in 0..3 {
            a.grad_r[c] = a.grad_r[c] * w0 + g.grad_r[c] * w1;
            a.grad_t[c] = a.grad_t[c] * w0 + g.grad_t[c] * w1;
        }
    }
}

/// A lookup's request to refine the record that served it best (see the module docs): gather
/// `rays` more hemisphere rays at `p` around `n` and hand them to [`IrradianceCache::refine`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Refine {
    index: usize,
    version: u64,
    pub p: Vec3,
    pub n: Vec3,
    /// The face's normal at the record (the rays start lifted along it; rays below it see
    /// nothing).
    pub ng: Vec3,
    pub rays: u32,
}

/// Counters of a cache's work (for tests and logs).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CacheStats {
    pub records: usize,
    /// Records dropped because a moved object could change them.
    pub invalidated: u64,
    /// Records dropped to stay within [`MAX_RECORDS`].
    pub evicted: u64,
    /// Gathers added to existing records.
    pub refined: u64,
}

/// One scene's irradiance cache on a worker (see the module docs).
pub struct IrradianceCache {
    cell: f32,
    state: RwLock<(State, CacheStats)>,
}

impl IrradianceCache {
    /// An empty cache for a scene with these bounds.
    pub fn new((lo, hi): (Vec3, Vec3)) -> IrradianceCache {
        let diag = (hi - lo).length();
        let cell = if diag.is_finite() && diag > 0.0 { diag / CELLS_ACROSS } else { 1.0 };
        let state = State { settings: None, transforms: Vec::new(), version: 0, records: Vec::new(), raw: Vec::new(), uses: Vec::new(), next: 0, grid: Grid::default() };
        IrradianceCache { cell, state: RwLock::new((state, CacheStats::default())) }
    }

    fn cell_of(&self, p: Vec3) -> [i32; 3] {
        let c = (p / self.cell).floor().clamp(Vec3::splat(-1e6), Vec3::splat(1e6));
        [c.x as i32, c.y as i32, c.z as i32]
    }

    fn key(&self, p: Vec3) -> u64 {
        pack(self.cell_of(p))
    }

    /// The clamp range of R for accuracy `a`: a record serves at most a·R ≤ one cell away.
    pub fn radius_range(&self, a: f32) -> (f32, f32) {
        let r_max = self.cell / a;
        (r_max / R_RANGE, r_max)
    }

    pub fn stats(&self) -> CacheStats {
        let g = self.state.read().unwrap_or_else(|p| p.into_inner());
        CacheStats { records: g.0.records.len(), ..g.1 }
    }

    /// Brings the cache to a batch's object placements and settings (dropping what they
    /// invalidate, module docs) and returns the batch's ticket.
    pub fn sync(&self, scene: &Scene, transforms: &[Affine3A], settings: CacheSettings) -> Ticket {
        let mut g = self.state.write().unwrap_or_else(|p| p.into_inner());
        let (s, stats) = &mut *g;
        if s.settings != Some(settings) {
            s.records.clear();
            s.raw.clear();
            s.uses.clear();
            s.grid.clear();
            s.next = 0;
            s.settings = Some(settings);
            s.transforms = transforms.to_vec();
            s.version += 1;
        } else if s.transforms.as_slice() != transforms {
            let mut moved: Vec<(u32, [Vec3; 8], [Vec3; 8])> = Vec::new();
            for (i, o) in scene.objects.iter().enumerate() {
                let (old, new) = (s.transforms.get(i), transforms.get(i));
                if old != new {
                    let b = o.mesh.bounds;
                    let boxes = |t: Option<&Affine3A>| box_corners(transformed_box(t.unwrap_or(&o.transform), b));
                    moved.push((i as u32, boxes(old), boxes(new)));
                }
            }
            let sees = |r: &Record| {
                moved.iter().any(|(obj, old, new)| *obj == r.object || old.iter().chain(new).any(|c| r.n.dot(*c - r.p) > 0.0))
            };
            let before = s.records.len();
            let keep: Vec<bool> = s.records.iter().map(|r| !sees(r)).collect();
            retain_where(&mut s.records, &keep);
            retain_where(&mut s.raw, &keep);
            retain_where(&mut s.uses, &keep);
            stats.invalidated += (before - s.records.len()) as u64;
            // Rebuild the grid over the kept records (indices moved).
            s.grid.clear();
            for i in 0..s.records.len() {
                s.link(self.key(s.records[i].p), i);
            }
            s.next = 0;
            s.transforms = transforms.to_vec();
            s.version += 1;
        }
        Ticket { version: s.version, settings }
    }

    /// Interpolated irradiance at (p, n), or `None` where no record is valid (or the ticket
    /// is stale).
    pub fn lookup(&self, t: &Ticket, p: Vec3, n: Vec3) -> Option<Vec3> {
        self.lookup_counted(t, p, n).map(|(e, _)| e)
    }

    /// [`Self::lookup`], counting the lookup against the record of the highest weight; once
    /// that record has served a quarter as many lookups as it holds rays
    /// ([`REFINE_USES_PER_RAYS`]) and holds fewer than the settings' `max_rays`, the lookup
    /// also returns the request to refine it.
    pub fn lookup_counted(&self, t: &Ticket, p: Vec3, n: Vec3) -> Option<(Vec3, Option<Refine>)> {
        let g = self.state.read().unwrap_or_else(|p| p.into_inner());
        let s = &g.0;
        if s.version != t.version {
            return None;
        }
        let inv_a = 1.0 / t.settings.error;
        let a = t.settings.error;
        let a2 = a * a * (1.0 + 1e-4);
        let c = self.cell_of(p);
        // Where p lies in its cell (0..1 per axis): a neighbour cell nearer than a whole cell
        // can hold a record that reaches p (a record serves within a·R ≤ one cell); the
        // others cannot, and are skipped (a little slack for rounding). Cells at the clamp
        // are all visited.
        let f = p / self.cell - Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32);
        let exact = f.cmpge(Vec3::ZERO).all() && f.cmple(Vec3::ONE).all();
        let gap = |d: i32, f: f32| match d {
            -1 => f * f,
            1 => (1.0 - f) * (1.0 - f),
            _ => 0.0,
        };
        const REACH: f32 = 1.0 + 1e-3;
        let (mut sum, mut wsum) = (Vec3::ZERO, 0.0f32);
        let mut best = (0.0f32, usize::MAX);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if exact && gap(dx, f.x) + gap(dy, f.y) + gap(dz, f.z) >= REACH * REACH {
                        continue;
                    }
                    let Some(entries) = s.grid.get(&pack([c[0] + dx, c[1] + dy, c[2] + dz])) else { continue };
                    for e in entries {
                        // Most of a cell's records are out of reach: w > 1/a needs both
                        // |p - pᵢ| < a·Rᵢ and 1 - n·nᵢ < a², tested first without a square
                        // root or a division (a margin for rounding; the weight decides).
                        let d = p - e.p;
                        let reach = a * e.r * (1.0 + 1e-4);
                        if d.length_squared() >= reach * reach || 1.0 - n.dot(e.n) >= a2 {
                            continue;
                        }
                        let w = ward_weight(e.p, e.n, e.r, p, n);
                        // Ward's "in front" test: a record whose point lies in front of p
                        // (toward the normals) sees a different neighbourhood.
                        if w <= inv_a || (p - e.p).dot(n + e.n) < -0.1 * e.r {
                            continue;
                        }
                        let i = e.index as usize;
                        sum += s.records[i].extrapolate(p, n) * w;
                        wsum += w;
                        if w > best.0 {
                            best = (w, i);
                        }
                    }
                }
            }
        }
        if wsum <= 0.0 {
            return None;
        }
        let mut refine = None;
        let i = best.1;
        let r = &s.records[i];
        if r.rays < t.settings.max_rays {
            let uses = s.uses[i].fetch_add(1, Ordering::Relaxed) + 1;
            if uses == (r.rays / REFINE_USES_PER_RAYS).max(1) {
                refine = Some(Refine { index: i, version: s.version, p: r.p, n: r.n, ng: s.raw[i].ng, rays: t.settings.rays });
            }
        }
        Some((sum / wsum, refine))
    }

    /// Adds gather `g` (of `req.rays` rays, made as `req` asked) to the record `req` came
    /// from, unless the cache has changed since or the record has been replaced; R and the
    /// gradient bounds are applied anew to the merged gathers.
    pub fn refine(&self, t: &Ticket, req: &Refine, g: &Gathered) {
        if !(g.e.is_finite() && g.grad_r.iter().chain(&g.grad_t).all(|v| v.is_finite())) {
            return;
        }
        let mut guard = self.state.write().unwrap_or_else(|p| p.into_inner());
        let (s, stats) = &mut *guard;
        let i = req.index;
        if s.version != req.version || s.records.get(i).is_none_or(|r| r.p != req.p || r.n != req.n) {
            return;
        }
        let rays = s.records[i].rays;
        s.raw[i].merge(rays, g, req.rays);
        let total = rays + req.rays;
        let (r, grad_r, grad_t) = self.served(&s.raw[i].g, t.settings.error);
        let rec = &mut s.records[i];
        (rec.e, rec.r, rec.grad_r, rec.grad_t, rec.rays) = (s.raw[i].g.e, r, grad_r, grad_t, total);
        // The weight test reads R from the record's entry in its cell.
        let key = self.key(rec.p);
        if let Some(e) = s.grid.get_mut(&key).and_then(|v| v.iter_mut().find(|e| e.index as usize == i)) {
            e.r = r;
        }
        s.uses[i].store(0, Ordering::Relaxed);
        stats.refined += 1;
    }

    /// What a record serves from its gathers `g`: R clamped (module docs) and the bounded
    /// gradients.
    fn served(&self, g: &Gathered, a: f32) -> (f32, [Vec3; 3], [Vec3; 3]) {
        let (r_min, r_max) = self.radius_range(a);
        let lum = |v: Vec3| v.x + v.y + v.z;
        let gt_len = (g.grad_t[0] + g.grad_t[1] + g.grad_t[2]).length();
        let mut r = g.r.min(r_max);
        if gt_len > 0.0 && lum(g.e) > 0.0 {
            r = r.min(lum(g.e) / gt_len);
        }
        let r = if r.is_nan() { r_max } else { r.max(r_min) };
        let finite = |a: &[Vec3; 3]| a.iter().all(|v| v.is_finite());
        let (grad_r, grad_t) = if finite(&g.grad_r) && finite(&g.grad_t) { (g.grad_r, g.grad_t) } else { ([Vec3::ZERO; 3], [Vec3::ZERO; 3]) };
        let (grad_r, grad_t) = limit_gradients(g.e, r, grad_r, grad_t);
        (r, grad_r, grad_t)
    }

    /// Stores a record made from `g` at (p, n) on `object` (R clamped; module docs) and
    /// returns it; stored only if the ticket is current and the record finite.
    /// `ng`: the face's normal at p (refinement gathers over it again).
    pub fn insert(&self, t: &Ticket, p: Vec3, n: Vec3, object: u32, g: &Gathered, ng: Vec3) -> Record {
        let (r, grad_r, grad_t) = self.served(g, t.settings.error);
        let rec = Record { p, n, e: g.e, r, grad_r, grad_t, object, rays: t.settings.rays };
        let raw = Raw { g: *g, ng };
        if !(g.e.is_finite() && p.is_finite() && n.is_finite()) {
            return rec;
        }
        let mut guard = self.state.write().unwrap_or_else(|p| p.into_inner());
        let (s, stats) = &mut *guard;
        if s.version != t.version {
            return rec;
        }
        let key = self.key(p);
        if s.records.len() < MAX_RECORDS {
            s.records.push(rec);
            s.raw.push(raw);
            s.uses.push(AtomicU32::new(0));
            s.link(key, s.records.len() - 1);
        } else {
            let i = s.next;
            s.next = (s.next + 1) % MAX_RECORDS;
            let old_key = self.key(s.records[i].p);
            if let Some(entries) = s.grid.get_mut(&old_key) {
                entries.retain(|e| e.index as usize != i);
                if entries.is_empty() {
                    s.grid.remove(&old_key);
                }
            }
            s.records[i] = rec;
            s.raw[i] = raw;
            s.uses[i].store(0, Ordering::Relaxed);
            s.link(key, i);
            stats.evicted += 1;
        }
        rec
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A point at (x0, 0, 0) facing +z under a plane at height h whose radiance is 1 where
    /// x > 0 and 0 elsewhere (an occlusion edge, what the gradients are made for).
    fn half_plane(x0: f32, h: f32) -> impl Fn(Vec3) -> (Vec3, f32) {
        move |d: Vec3| {
            if d.z <= 0.0 {
                return (Vec3::ZERO, f32::INFINITY);
            }
            let t = h / d.z;
            (Vec3::splat(if x0 + t * d.x > 0.0 { 1.0 } else { 0.0 }), t)
        }
    }

    /// The closed form: the half-plane's projected solid angle is half the unit disk plus
    /// half an ellipse of semi-axis c / √(1 + c²), c = x0 / h, so
    /// E(x0) = π/2 (1 + x0 / √(x0² + h²)) and dE/dx0 = π/2 · h² / (x0² + h²)^{3/2}.
    fn exact(x0: f32, h: f32) -> (f32, f32) {
        let q = x0 * x0 + h * h;
        (PI / 2.0 * (1.0 + x0 / q.sqrt()), PI / 2.0 * h * h / q.powf(1.5))
    }

    #[test]
    fn gathered_irradiance_and_gradients_match_the_half_plane_closed_form() {
        let frame = Frame::from_normal(Vec3::Z);
        for (x0, h) in [(0.3f32, 1.0f32), (-0.5, 2.0), (0.0, 0.5)] {
            let (e, de) = exact(x0, h);
            let runs = 16;
            let (mut ge, mut gt, mut gr) = (0.0, Vec3::ZERO, Vec3::ZERO);
            for seed in 0..runs {
                let g = gather(&frame, 1024, &mut Rng::new(seed, 1), half_plane(x0, h));
                ge += g.e.x / runs as f32;
                gt += g.grad_t[0] / runs as f32;
                gr += g.grad_r[0] / runs as f32;
            }
            assert!((ge - e).abs() < 0.01 * e, "E at {x0}, {h}: {ge} vs {e}");
            // Ward & Heckbert's estimate is itself an approximation of the derivative at
            // the strata's resolution: 10 %.
            assert!((gt.x - de).abs() < 0.1 * de, "dE/dx at {x0}, {h}: {} vs {de}", gt.x);
            assert!(gt.y.abs() < 0.05 * de && gt.z.abs() < 1e-6, "{gt}");
            // Rotation: tilting the normal toward +x by β changes E by β ∫ L ω_x dω, and
            // (n_i × n)·∇r = β ∇r.y. The integral by a fine midpoint rule in (θ, φ):
            let steps = 1000;
            let mut rot = 0.0f64;
            for i in 0..steps {
                let th = (i as f64 + 0.5) / steps as f64 * std::f64::consts::FRAC_PI_2;
                for j in 0..steps {
                    let ph = (j as f64 + 0.5) / steps as f64 * std::f64::consts::TAU;
                    let d = Vec3::new((th.sin() * ph.cos()) as f32, (th.sin() * ph.sin()) as f32, th.cos() as f32);
                    let l = half_plane(x0, h)(d).0.x as f64;
                    rot += l * th.sin() * ph.cos() * th.sin() * (std::f64::consts::FRAC_PI_2 / steps as f64) * (std::f64::consts::TAU / steps as f64);
                }
            }
            assert!((gr.y as f64 - rot).abs() < 0.1 * rot.abs().max(0.1), "rotation at {x0}, {h}: {} vs {rot}", gr.y);
        }
    }

    /// A record whose estimated gradients are far too large (hemisphere rays hitting a wall
    /// at almost no distance: E / |∇t| far below Rmin) extrapolates by at most a·E per
    /// gradient at every point it serves, on random cases; gradients within the bounds are
    /// kept as they are.
    #[test]
    fn extrapolation_stays_within_a_of_the_record_whatever_its_gradients() {
        let cache = IrradianceCache::new((Vec3::ZERO, Vec3::splat(32.0)));
        let scene = Scene { objects: vec![], ..edgepoint_scene::builtin::load("cornell").unwrap() };
        let mut rng = Rng::new(5, 9);
        let mut served = 0;
        for case in 0..200 {
            let a = 0.05 + 0.3 * rng.next_f32();
            let settings = CacheSettings { error: a, rays: 64, max_depth: 2, max_rays: 64 };
            let t = cache.sync(&scene, &[], settings);
            let (r_min, _) = cache.radius_range(a);
            let e = Vec3::new(0.1, 0.5, 2.0) * (0.5 + rng.next_f32());
            let mut big = |s: f32| Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, 0.0) * s;
            let scale = if case % 2 == 0 { 1e4 } else { 1e-3 };
            let g = Gathered { e, r: r_min * 1e-3, grad_r: [big(scale), big(scale), big(scale)], grad_t: [big(scale), big(scale), big(scale)] };
            let p0 = Vec3::splat(10.0) + Vec3::new(rng.next_f32(), 0.0, rng.next_f32());
            let rec = cache.insert(&t, p0, Vec3::Z, 0, &g, Vec3::Z);
            assert_eq!(rec.r, r_min, "R raised to Rmin");
            if scale < 1.0 {
                assert_eq!((rec.grad_r, rec.grad_t), (g.grad_r, g.grad_t), "small gradients kept");
            }
            for _ in 0..50 {
                // A point and normal the record serves: d/R + √(1 − n·nᵢ) < a.
                let d = Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, 0.0).normalize_or_zero() * rec.r * a * rng.next_f32();
                let tilt = Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, 0.0) * a * 1.4;
                let n = (Vec3::Z + tilt).normalize();
                if rec.weight(p0 + d, n) <= 1.0 / a {
                    continue;
                }
                served += 1;
                let x = rec.extrapolate(p0 + d, n);
                for c in 0..3 {
                    assert!((x[c] - e[c]).abs() <= 2.0 * a * e[c] * 1.0001, "case {case}: channel {c}: {} from {} at a = {a}", x[c], e[c]);
                }
            }
        }
        assert!(served > 2000, "{served}");
    }

    /// Refinement's bookkeeping: a record asks for more rays after serving a quarter as many
    /// lookups as it holds rays (16, then 32, ...), gets the rays-weighted mean of its gathers, stops at
    /// `max_rays`, and a request that outlived a change of the cache is dropped. Its value:
    /// refined from one gather to 64 on the half plane, E's standard error falls below 1 %
    /// (single gathers scatter by several per cent) and E lies within 4 standard errors of
    /// the closed form.
    #[test]
    fn records_refine_as_they_are_used_and_converge() {
        let cache = IrradianceCache::new((Vec3::ZERO, Vec3::splat(32.0)));
        let scene = Scene { objects: vec![], ..edgepoint_scene::builtin::load("cornell").unwrap() };
        let settings = CacheSettings { error: 0.2, rays: 64, max_depth: 2, max_rays: 4096 };
        let t = cache.sync(&scene, &[], settings);
        let frame = Frame::from_normal(Vec3::Z);
        let (x0, h) = (0.3f32, 1.0f32);
        let (exact_e, _) = exact(x0, h);
        let mut rng = Rng::new(11, 2);
        let p = Vec3::splat(10.0);
        let first = gather(&frame, 64, &mut rng, half_plane(x0, h));
        cache.insert(&t, p, Vec3::Z, 0, &first, Vec3::Z);
        let mut es = vec![first.e.x as f64];
        let mut sum_e = first.e.x as f64;
        let mut gathers = 1;
        let mut lookups = 0;
        loop {
            let (_, req) = cache.lookup_counted(&t, p, Vec3::Z).unwrap();
            lookups += 1;
            let Some(req) = req else {
                assert!(lookups < 100_000, "refinement stopped");
                if cache.stats().refined == 63 {
                    break;
                }
                continue;
            };
            let rays_before = 64 * gathers;
            assert_eq!(lookups, rays_before / REFINE_USES_PER_RAYS, "asked after a quarter as many lookups as rays");
            assert_eq!((req.p, req.n, req.ng, req.rays), (p, Vec3::Z, Vec3::Z, 64));
            let g = gather(&frame, 64, &mut rng, half_plane(x0, h));
            cache.refine(&t, &req, &g);
            sum_e += g.e.x as f64;
            es.push(g.e.x as f64);
            gathers += 1;
            lookups = 0;
            let e = cache.lookup(&t, p, Vec3::Z).unwrap().x as f64;
            lookups += 1;
            assert!((e - sum_e / gathers as f64).abs() < 1e-4 * e, "the mean of {gathers} gathers: {e} vs {}", sum_e / gathers as f64);
            if gathers == 64 {
                break;
            }
        }
        assert_eq!(cache.stats().refined, 63);
        // At max_rays: no more requests.
        for _ in 0..10_000 {
            assert!(cache.lookup_counted(&t, p, Vec3::Z).unwrap().1.is_none());
        }
        let e = cache.lookup(&t, p, Vec3::Z).unwrap().x as f64;
        let mean = sum_e / es.len() as f64;
        let sd = (es.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (es.len() - 1) as f64).sqrt();
        let se = sd / (es.len() as f64).sqrt();
        let exact_e = exact_e as f64;
        assert!(sd > 0.02 * exact_e && se < 0.01 * exact_e, "one gather's sd {sd}, refined {se}");
        assert!((e - exact_e).abs() < 4.0 * se, "refined: {e} vs {exact_e} (standard error {se})");
        // A request that outlived a change of settings does nothing.
        let t2 = cache.sync(&scene, &[], CacheSettings { max_rays: 128, ..settings });
        cache.insert(&t2, p, Vec3::Z, 0, &first, Vec3::Z);
        let req = (0..64).find_map(|_| cache.lookup_counted(&t2, p, Vec3::Z).unwrap().1).unwrap();
        cache.sync(&scene, &[], CacheSettings { max_rays: 256, ..settings });
        let before = cache.stats().refined;
        cache.refine(&t2, &req, &first);
        assert_eq!(cache.stats().refined, before);
    }

    #[test]
    fn records_serve_within_their_radius_and_extrapolate_with_gradients() {
        let cache = IrradianceCache::new((Vec3::ZERO, Vec3::splat(32.0)));
        let settings = CacheSettings { error: 0.2, rays: 64, max_depth: 2, max_rays: 64 };
        let scene = Scene { objects: vec![], ..edgepoint_scene::builtin::load("cornell").unwrap() };
        let t = cache.sync(&scene, &[], settings);
        let g = Gathered { e: Vec3::splat(2.0), r: 2.0, grad_r: [Vec3::ZERO; 3], grad_t: [Vec3::new(0.5, 0.0, 0.0); 3] };
        let rec = cache.insert(&t, Vec3::splat(10.0), Vec3::Y, 0, &g, Vec3::Y);
        // R: 2 is inside [Rmax/16, Rmax] (cell 1.73, Rmax 8.7) and below E/|∇t| = 6/1.5.
        assert_eq!(rec.r, 2.0);
        let at = |dx: f32| cache.lookup(&t, Vec3::splat(10.0) + Vec3::new(dx, 0.0, 0.0), Vec3::Y);
        assert_eq!(at(0.0), Some(Vec3::splat(2.0)));
        assert!((at(0.3).unwrap() - Vec3::splat(2.15)).abs().max_element() < 1e-5, "extrapolated with ∇t");
        // Weight 1/(d/R) must exceed 1/a: d < a R = 0.4.
        assert!(at(0.39).is_some() && at(0.41).is_none());
        // A normal turned away beyond the same budget: √(1 − cos) ≥ a.
        assert!(cache.lookup(&t, Vec3::splat(10.0), Vec3::new(0.0, 0.9, 0.436).normalize()).is_none());
        // A different setting empties the cache and stales the old ticket.
        let t2 = cache.sync(&scene, &[], CacheSettings { error: 0.3, ..settings });
        assert!(cache.lookup(&t2, Vec3::splat(10.0), Vec3::Y).is_none() && cache.lookup(&t, Vec3::splat(10.0), Vec3::Y).is_none());
        cache.insert(&t, Vec3::splat(10.0), Vec3::Y, 0, &g, Vec3::Y);
        assert_eq!(cache.stats().records, 0, "a stale ticket stores nothing");
    }
    /// The lookup against every record (the brute-force oracle): the same weighted mean, the
    /// same best record.
    fn lookup_by_every_record(cache: &IrradianceCache, a: f32, p: Vec3, n: Vec3) -> Option<(Vec3, usize)> {
        let g = cache.state.read().unwrap();
        let (mut sum, mut wsum, mut best) = (Vec3::ZERO, 0.0f32, (0.0f32, usize::MAX));
        for (i, r) in g.0.records.iter().enumerate() {
            let w = r.weight(p, n);
            if w <= 1.0 / a || (p - r.p).dot(n + r.n) < -0.1 * r.r {
                continue;
            }
            sum += r.extrapolate(p, n) * w;
            wsum += w;
            if w > best.0 {
                best = (w, i);
            }
        }
        (wsum > 0.0).then(|| (sum / wsum, best.1))
    }

    #[test]
    fn lookups_find_what_a_scan_of_every_record_finds() {
        let (lo, hi) = (Vec3::new(-1.0, 0.0, -2.0), Vec3::new(3.0, 2.0, 1.0));
        let cache = IrradianceCache::new((lo, hi));
        let scene = Scene { objects: vec![], ..edgepoint_scene::builtin::load("cornell").unwrap() };
        let settings = CacheSettings { error: 0.25, rays: 16, max_depth: 2, max_rays: 64 };
        let t = cache.sync(&scene, &[], settings);
        let (r_min, r_max) = cache.radius_range(settings.error);
        let mut rng = Rng::new(5, 1);
        let mut u = move || rng.next_f32();
        let dir = |u: &mut dyn FnMut() -> f32| Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize_or(Vec3::Y);
        // Records on a few planes and scattered, of every R from below Rmin to beyond Rmax.
        for k in 0..3000 {
            let p = if k % 3 == 0 { Vec3::new(lo.x + u() * 4.0, 0.0, lo.z + u() * 3.0) } else { lo + Vec3::new(u() * 4.0, u() * 2.0, u() * 3.0) };
            let n = if k % 3 == 0 { Vec3::Y } else { dir(&mut u) };
            let r = r_min * 0.5 + u() * (r_max * 1.5);
            let g = Gathered { e: Vec3::new(u(), u(), u()) + 0.1, r, grad_r: [dir(&mut u) * 0.1; 3], grad_t: [dir(&mut u) * 0.2; 3] };
            cache.insert(&t, p, n, 0, &g, n);
        }
        // Some refined (their R changes).
        let mut refined = 0;
        for k in 0..20_000 {
            let p = lo + Vec3::new(u() * 4.0, u() * 2.0, u() * 3.0);
            let p = if k % 2 == 0 { Vec3::new(p.x, 0.0, p.z) } else { p };
            if let Some((_, Some(req))) = cache.lookup_counted(&t, p, Vec3::Y) {
                let g = Gathered { e: Vec3::splat(0.5), r: r_min + u() * r_max, grad_r: [Vec3::ZERO; 3], grad_t: [Vec3::ZERO; 3] };
                cache.refine(&t, &req, &g);
                refined += 1;
            }
        }
        assert!(refined > 20, "{refined} refined");
        let (mut found, mut checked) = (0, 0);
        for k in 0..20_000 {
            // Points anywhere, on the plane, and on the cell boundaries.
            let mut p = lo + Vec3::new(u() * 4.0, u() * 2.0, u() * 3.0);
            if k % 3 == 0 {
                p.y = 0.0;
            }
            if k % 5 == 0 {
                p.x = (p.x / cache.cell).round() * cache.cell;
            }
            let n = if k % 2 == 0 { Vec3::Y } else { dir(&mut u) };
            let want = lookup_by_every_record(&cache, settings.error, p, n);
            let got = cache.lookup(&t, p, n);
            checked += 1;
            match (want, got) {
                (None, None) => {}
                (Some((w, _)), Some(g)) => {
                    found += 1;
                    assert!((w - g).abs().max_element() <= 1e-5 * w.abs().max_element().max(1.0), "at {p}: {g} vs every record's {w}");
                }
                _ => panic!("at {p} {n}: {got:?} vs every record's {want:?}"),
            }
        }
        assert!(found > checked / 10, "{found} of {checked} lookups served");
    }
}
