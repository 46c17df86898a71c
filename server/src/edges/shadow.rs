//! Shadow edges on receivers, kept from frame to frame (paper 000 §6.5 "Complex Scenes").
//!
//! "The shading process asynchronously communicates the light–blocker–receiver triples that
//! it discovers during shading to the edge finder. All shadow edges associated with a
//! receiver are stored with the receiver, and reused as long as the light, blocker and
//! receiver do not move."
//!
//! The store is organised by light–blocker pair, as the events are. A pair holds
//! - its shadow events ([`super::events`]), in the blocker's object space;
//! - per *participant* — the blocker itself and every receiver the triples name for the
//!   pair — the pieces each event cuts from it ([`super::wedge::search`]): the
//!   intersection lists of paper 002 §3.3, kept before visibility;
//! - per event the visible shadow edges, tagged with the receiver they lie on: the 1D
//!   clipping ([`super::clip1d`]) of all participants' pieces. The blocker always takes
//!   part, so a blocker edge hidden from the light by the blocker itself casts nothing; it
//!   only shows shadow edges if a triple names it as its own receiver.
//!
//! Moves (§6.5): when the light or the blocker moves, the pair's events and everything of
//! the pair are recomputed. When a receiver moves, only its own pieces are recomputed and
//! the events it touched (before or after) are clipped again from the stored pieces of the
//! others: that recomputes its shadows and those of the receivers sharing the pair that lie
//! farther from the light ("no longer occluded by the moved object") — exactly, and without
//! intersecting them again. New triples add receivers the same way. The result equals a
//! full recomputation (tested on random moves).
use super::clip1d::{self, ClipScratch, Seg, Visible};
use super::events::{find_events, Generator, LocalLight, ShadowEvent, VertexRings};
use super::face_bvh::FaceBvh;
use super::geometric::MeshEdgeTrees;
use super::umbra::{umbra_ends, UmbraEnds};
use super::wedge::{search, Piece, SearchScratch, Wedge};
use super::EdgeSegment;
use crate::edges::TripleKey;
use edgepoint_scene::{Light, Mesh, NO_FACE};
use glam::{Affine3A, DAffine3, DMat3};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Instant;

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The scene as the shadow store needs it (all per object, indexed by object id).
#[derive(Clone, Copy)]
pub struct ShadowScene<'a> {
    pub meshes: &'a [Arc<Mesh>],
    pub trees: &'a [MeshEdgeTrees],
    /// Vertex rings of the objects that block area lights (`None` elsewhere).
    pub rings: &'a [Option<VertexRings>],
    pub bvhs: &'a [FaceBvh],
    pub lights: &'a [Light],
    /// Current object-to-world transforms.
    pub transforms: &'a [Affine3A],
}

/// What one update did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ShadowUpdateStats {
    /// Finding events (ms).
    pub events_ms: f64,
    /// Searching intersections (ms).
    pub search_ms: f64,
    /// 1D clipping (ms).
    pub clip_ms: f64,
    /// Where umbral events stop bounding the umbra ([`super::umbra`], ms).
    pub umbra_ms: f64,
    /// Light–blocker pairs in the store.
    pub pairs: usize,
    /// Pairs whose events were (re)computed.
    pub pairs_recomputed: usize,
    /// Events found in those pairs.
    pub events_found: usize,
    /// (participant, event) intersections searched.
    pub intersections: usize,
    /// Events clipped again.
    pub events_clipped: usize,
    /// Shadow-edge segments stored after the update.
    pub segments: usize,
    /// Face-hierarchy nodes and leaves the searches visited, and faces they cut.
    pub nodes_visited: u64,
    pub leaves_visited: u64,
    pub faces_cut: u64,
}

impl ShadowUpdateStats {
    fn add_search(&mut self, c: [u64; 3]) {
        self.nodes_visited += c[0];
        self.leaves_visited += c[1];
        self.faces_cut += c[2];
    }
}

#[derive(Debug, Clone, Default)]
struct Part {
    receiver: bool,
    /// Pieces of event `i` are `pieces[off[i]..off[i + 1]]`.
    off: Vec<u32>,
    pieces: Vec<Piece>,
}

impl Part {
    fn of(&self, i: usize) -> &[Piece] {
        &self.pieces[self.off[i] as usize..self.off[i + 1] as usize]
    }
}

#[derive(Debug, Clone, Default)]
struct Pair {
    events: Vec<ShadowEvent>,
    parts: BTreeMap<u32, Part>,
    /// Per umbral event, where it stops bounding the umbra (from the events and the
    /// blocker's own pieces only).
    umbra: UmbraEnds,
    /// Visible shadow edges per event.
    visible: Vec<Vec<EdgeSegment>>,
}

/// Shadow edges of the scene, per light–blocker pair.
#[derive(Debug, Clone, Default)]
pub struct ShadowStore {
    pairs: BTreeMap<(u32, u32), Pair>,
}

/// An object transform in f64 (wedges and bands are computed in f64).
pub(crate) fn daffine(a: &Affine3A) -> DAffine3 {
    DAffine3 {
        matrix3: DMat3::from_cols(a.matrix3.x_axis.as_dvec3(), a.matrix3.y_axis.as_dvec3(), a.matrix3.z_axis.as_dvec3()),
        translation: a.translation.as_dvec3(),
    }
}

/// Faces of the blocker that touch the event's own blocker edge or vertex: they meet the
/// wedge only where it starts, and are left out when the blocker is searched.
fn own_faces(mesh: &Mesh, rings: Option<&VertexRings>, ev: &ShadowEvent) -> Vec<u32> {
    match ev.generator {
        Generator::Point { edge } | Generator::VE { edge, .. } => {
            let f = mesh.edges[edge as usize].faces;
            let mut v: Vec<u32> = f.iter().copied().filter(|&x| x != NO_FACE).collect();
            v.sort_unstable();
            v
        }
        Generator::EV { vertex, .. } => rings.map(|r| r.faces_of(vertex).to_vec()).unwrap_or_default(),
    }
}

/// The pieces every event of `events` (blocker `blocker`) cuts from participant `obj`, and
/// the search's (nodes, leaves, faces cut).
fn compute_part(scene: &ShadowScene, blocker: u32, events: &[ShadowEvent], obj: u32, receiver: bool) -> (Part, [u64; 3]) {
    let tb = daffine(&scene.transforms[blocker as usize]);
    let to_obj =
        if obj == blocker { DAffine3::IDENTITY } else { daffine(&scene.transforms[obj as usize]).inverse() * tb };
    let bvh = &scene.bvhs[obj as usize];
    let mesh = &scene.meshes[blocker as usize];
    let rings = scene.rings[blocker as usize].as_ref();
    let per: Vec<(Vec<Piece>, [u64; 3])> = events
        .par_iter()
        .map_init(SearchScratch::default, |scratch, ev| {
            let mut out = Vec::new();
            scratch.counts = [0; 3];
            if let Some(w) = Wedge::new(ev, &to_obj) {
                let exclude = if obj == blocker { own_faces(mesh, rings, ev) } else { Vec::new() };
                search(bvh, &w, &exclude, &mut out, scratch);
            }
            (out, scratch.counts)
        })
        .collect();
    let mut off = Vec::with_capacity(events.len() + 1);
    let mut pieces = Vec::with_capacity(per.iter().map(|p| p.0.len()).sum());
    let mut counts = [0u64; 3];
    off.push(0);
    for (p, c) in per {
        pieces.extend(p);
        off.push(pieces.len() as u32);
        for k in 0..3 {
            counts[k] += c[k];
        }
    }
    (Part { receiver, off, pieces }, counts)
}

/// Clips event `i` of a pair: the visible shadow edges on its receivers, in world space.
/// Reusable allocations of [`clip_event`].
#[derive(Default)]
struct ClipBuffers {
    clip: ClipScratch,
    segs: Vec<Seg>,
    /// (participant, can show a shadow edge) per piece.
    tags: Vec<(u32, bool)>,
    visible: Vec<Visible>,
}

/// Visible runs narrower than this (in the event's ray parameter `u`, a millionth of the
/// event's fan) are dropped: they are slivers where pieces that should meet leave a
/// hair's gap (e.g. two umbra-ending crossings from neighbouring events), far below a
/// pixel.
const MIN_RUN: f64 = 1e-6;

fn clip_event(ev: &ShadowEvent, i: usize, parts: &BTreeMap<u32, Part>, umbra: &UmbraEnds, world: &DAffine3, buf: &mut ClipBuffers) -> Vec<EdgeSegment> {
    let ClipBuffers { clip: cs, segs, tags, visible: vis } = buf;
    segs.clear();
    tags.clear();
    vis.clear();
    for (&obj, part) in parts {
        for p in part.of(i) {
            segs.push(Seg { a: p.a, b: p.b });
            tags.push((obj, p.output && part.receiver));
        }
    }
    // Past where an umbral event stops bounding the umbra it shows nothing.
    for s in umbra.of(i) {
        segs.push(*s);
        tags.push((u32::MAX, false));
    }
    if segs.is_empty() {
        return Vec::new();
    }
    clip1d::visible(segs, vis, cs);
    let Some(w) = Wedge::new(ev, world) else { return Vec::new() };
    let mut out = Vec::new();
    for v in vis.iter() {
        let (obj, output) = tags[v.piece];
        if !output || v.u1 - v.u0 < MIN_RUN {
            continue;
        }
        let s = &segs[v.piece];
        let a = w.point(clip1d::point_at(s, v.u0)).as_vec3();
        let b = w.point(clip1d::point_at(s, v.u1)).as_vec3();
        if a != b && a.is_finite() && b.is_finite() {
            out.push(EdgeSegment { a, b, kind: ev.kind, object: obj });
        }
    }
    out
}

impl ShadowStore {
    pub fn new() -> ShadowStore {
        ShadowStore::default()
    }

    /// Brings the store up to date: `triples` is the whole current set (pairs and receivers
    /// no longer named are dropped), `moved[o]` says object `o` moved since the last update
    /// and `light_moved[l]` the same of light `l`. Triples naming objects or lights the
    /// scene does not have are ignored.
    pub fn update(
        &mut self,
        scene: &ShadowScene,
        triples: impl IntoIterator<Item = TripleKey>,
        moved: &[bool],
        light_moved: &[bool],
    ) -> ShadowUpdateStats {
        let n = scene.meshes.len() as u32;
        let mut want: BTreeMap<(u32, u32), BTreeSet<u32>> = BTreeMap::new();
        for t in triples {
            if t.blocker < n && t.receiver < n && (t.light as usize) < scene.lights.len() {
                want.entry((t.light, t.blocker)).or_default().insert(t.receiver);
            }
        }
        self.pairs.retain(|k, _| want.contains_key(k));
        let mut stats = ShadowUpdateStats::default();
        let is = |v: &[bool], i: u32| v.get(i as usize).copied().unwrap_or(false);
        for (&(l, b), receivers) in &want {
            let fresh = !self.pairs.contains_key(&(l, b)) || is(moved, b) || is(light_moved, l);
            let pair = self.pairs.entry((l, b)).or_default();
            let world = daffine(&scene.transforms[b as usize]);
            if fresh {
                let mesh = &scene.meshes[b as usize];
                let local = LocalLight::new(&scene.lights[l as usize], &scene.transforms[b as usize]);
                let t = Instant::now();
                pair.events = find_events(mesh, &scene.trees[b as usize], scene.rings[b as usize].as_ref(), &local);
                stats.events_ms += ms(t);
                stats.pairs_recomputed += 1;
                stats.events_found += pair.events.len();
                pair.parts.clear();
                let mut objs: BTreeSet<u32> = receivers.clone();
                objs.insert(b);
                let t = Instant::now();
                for o in objs {
                    let (part, c) = compute_part(scene, b, &pair.events, o, receivers.contains(&o));
                    pair.parts.insert(o, part);
                    stats.intersections += pair.events.len();
                    stats.add_search(c);
                }
                stats.search_ms += ms(t);
                let t = Instant::now();
                pair.umbra = match (&scene.lights[l as usize], pair.parts.get(&b)) {
                    (Light::Area { vertices, .. }, Some(own)) => {
                        let mesh = &scene.meshes[b as usize];
                        umbra_ends(&pair.events, |i| own.of(i), vertices.len(), |e, w| mesh.edges[e as usize].v.contains(&w))
                    }
                    _ => UmbraEnds::default(),
                };
                stats.umbra_ms += ms(t);
                let parts = &pair.parts;
                let events = &pair.events;
                let umbra = &pair.umbra;
                let t = Instant::now();
                pair.visible = (0..events.len())
                    .into_par_iter()
                    .map_init(ClipBuffers::default, |s, i| clip_event(&events[i], i, parts, umbra, &world, s))
                    .collect();
                stats.clip_ms += ms(t);
                stats.events_clipped += events.len();
                continue;
            }
            // Incremental: find the events whose clipping can change.
            let ne = pair.events.len();
            let mut dirty = vec![false; ne];
            let mark = |part: &Part, dirty: &mut [bool]| {
                for (i, d) in dirty.iter_mut().enumerate() {
                    if part.off[i] != part.off[i + 1] {
                        *d = true;
                    }
                }
            };
            // Receivers no longer named (the blocker always stays).
            let gone: Vec<u32> = pair.parts.keys().copied().filter(|o| *o != b && !receivers.contains(o)).collect();
            for o in gone {
                if let Some(p) = pair.parts.remove(&o) {
                    mark(&p, &mut dirty);
                }
            }
            // Role changes (the blocker named as its own receiver or no longer).
            for (o, part) in pair.parts.iter_mut() {
                let r = receivers.contains(o);
                if part.receiver != r {
                    part.receiver = r;
                    mark(part, &mut dirty);
                }
            }
            // Moved participants and new receivers.
            let mut todo: Vec<u32> = pair.parts.keys().copied().filter(|&o| is(moved, o)).collect();
            todo.extend(receivers.iter().copied().filter(|o| !pair.parts.contains_key(o)));
            let t = Instant::now();
            for o in todo {
                if let Some(old) = pair.parts.get(&o) {
                    mark(old, &mut dirty);
                }
                let (part, c) = compute_part(scene, b, &pair.events, o, receivers.contains(&o));
                stats.intersections += ne;
                stats.add_search(c);
                mark(&part, &mut dirty);
                pair.parts.insert(o, part);
            }
            stats.search_ms += ms(t);
            let idx: Vec<usize> = (0..ne).filter(|&i| dirty[i]).collect();
            if idx.is_empty() {
                continue;
            }
            let parts = &pair.parts;
            let events = &pair.events;
            let umbra = &pair.umbra;
            let t = Instant::now();
            let redone: Vec<(usize, Vec<EdgeSegment>)> = idx
                .par_iter()
                .map_init(ClipBuffers::default, |s, &i| (i, clip_event(&events[i], i, parts, umbra, &world, s)))
                .collect();
            stats.clip_ms += ms(t);
            stats.events_clipped += redone.len();
            for (i, v) in redone {
                pair.visible[i] = v;
            }
        }
        stats.pairs = self.pairs.len();
        stats.segments = self.segment_count();
        stats
    }

    pub fn segment_count(&self) -> usize {
        self.pairs.values().flat_map(|p| p.visible.iter()).map(Vec::len).sum()
    }

    /// Appends every stored shadow edge whose receiver passes `keep`.
    pub fn append(&self, out: &mut Vec<EdgeSegment>, keep: impl Fn(u32) -> bool) {
        for p in self.pairs.values() {
            for v in &p.visible {
                out.extend(v.iter().filter(|s| keep(s.object)));
            }
        }
    }

    /// Events of a pair, if stored.
    pub fn events(&self, light: u32, blocker: u32) -> Option<&[ShadowEvent]> {
        self.pairs.get(&(light, blocker)).map(|p| p.events.as_slice())
    }

    /// Every stored event with the shadow edges it produced.
    pub fn events_with_edges(&self) -> impl Iterator<Item = ((u32, u32), &ShadowEvent, &[EdgeSegment])> {
        self.pairs.iter().flat_map(|(k, p)| p.events.iter().zip(&p.visible).map(move |(e, v)| (*k, e, v.as_slice())))
    }
}
