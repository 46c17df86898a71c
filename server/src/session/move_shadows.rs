//! Whether a move changed a point's shadow from a point light, exactly (the session's
//! [`ShadowQuery`] for [`crate::render_cache::reshadow`], and the same test for samples
//! shaded before moves that arrive after them).
//!
//! A point light's shadow at `p` from an object is the segment from `p` to the light
//! meeting one of the object's triangles. A rigid move leaves the triangles as they are in
//! object space, so the test runs there, against the object's face hierarchy
//! ([`FaceBvh`], built once per object at its first move), with the segment taken into
//! object space by the inverse of each transform.
//!
//! An area light's shading at `p` depends on the part of the light visible from `p` (paper
//! 002 §1's backprojection). The object alone hides nothing of it, part of it, or all of it
//! ([`hidden_by`]). Hiding nothing in both places, or all of it in both (the light
//! contributes nothing either way), the point's shading is unchanged; otherwise it shifted
//! by at most the share of the light hidden in one place only ([`shift_by`]), which the
//! cache adds up per point: a little (the object's penumbra moving on as it moves), the
//! point is shown stale; much (an old umbra now lit), it is dropped. (Before stop 38, every
//! point the swept box could shadow was marked stale and shown until re-shaded: where the
//! old soft shadow lay, its dark points stayed as speckles for 10–20 frames; at stop 38
//! every changed point was dropped, and the penumbra of an object that kept moving stayed
//! empty.) The test is exact and cheap for objects made of convex closed solids (boxes,
//! spheres, a chair's parts: each solid's shadow is one convex polygon, subtracted once);
//! other objects' points are marked stale as before (a torus's hundreds of triangles per
//! point made a frame in motion take seconds).
use crate::edges::face_bvh::FaceBvh;
use crate::render_cache::reshadow::{ShadowChange, ShadowQuery};
use crate::render_cache::{segment_hits_box, LightBound};
use edgepoint_scene::backprojection::{LightPlane, Visible};
use crate::dmesh::geometry::Geometry;
use edgepoint_scene::geometry::ray_triangle;
use edgepoint_scene::{Light, NoProgress, Scene};
use glam::{Affine3A, DVec3, Vec3};
use std::sync::Arc;

/// Objects with more triangles get no exact test (their moves mark points stale, as
/// before): the hierarchy is built on the frame thread at the object's first move, which
/// must stay a few milliseconds.
pub const MAX_EXACT_TRIANGLES: usize = 1 << 16;

/// A shadow ray's ends are left out by this fraction of its length: a receiver touching the
/// object (the floor under a box) is not shadowed by the face it touches, and the light
/// itself is not a blocker.
const END_MARGIN: f32 = 1e-4;

/// Objects with more triangles get no exact area-light test (their moves mark the points an
/// area light may light differently stale): each point tests every solid of the object
/// its pyramid to the light meets.
pub const MAX_EXACT_AREA_TRIANGLES: usize = 4096;

/// What a move's exact tests need of one object, made at its first move.
pub struct Exact {
    /// Its face hierarchy (point lights).
    pub bvh: FaceBvh,
    /// Its triangles grouped by convex closed solid, when every triangle is in one (area
    /// lights), each with whether its winding normal points out of the solid; `None`
    /// otherwise.
    pub solids: Option<Vec<Vec<(u32, bool)>>>,
}

/// Per object, what its exact tests need once it has moved (`None` inside: too large); per
/// light, its polygon if it is an area light.
pub struct MoveShadows {
    exact: Vec<Option<Option<Exact>>>,
    areas: Vec<Option<LightPlane>>,
}

/// `mesh`'s triangles grouped by convex closed solid (the discontinuity mesh's
/// [`crate::dmesh::solid::Solids`]), each with whether its winding normal points out of the
/// solid, if every triangle is in one.
pub fn convex_solids(mesh: &edgepoint_scene::Mesh) -> Option<Vec<Vec<(u32, bool)>>> {
    let g = Geometry::from_objects(&[(mesh.positions.iter().map(|p| p.as_dvec3()).collect(), mesh.triangles.clone())]);
    let mut by: std::collections::BTreeMap<u32, Vec<(u32, bool)>> = std::collections::BTreeMap::new();
    for t in 0..mesh.triangles.len() as u32 {
        by.entry(g.solids.convex_component(t)?).or_default().push((t, g.solids.outward[t as usize]));
    }
    Some(by.into_values().collect())
}

impl MoveShadows {
    pub fn new(scene: &Scene) -> Self {
        let areas = scene.lights.iter().map(|l| match l {
            Light::Area { vertices, .. } => LightPlane::new(vertices),
            _ => None,
        });
        MoveShadows { exact: (0..scene.objects.len()).map(|_| None).collect(), areas: areas.collect() }
    }

    /// Per light (the scene's order), its polygon if it is an area light.
    pub fn areas(&self) -> &[Option<LightPlane>] {
        &self.areas
    }

    /// Builds what `object`'s exact tests need if not yet done (at most once per object).
    pub fn prepare(&mut self, scene: &Scene, object: u32) {
        let slot = &mut self.exact[object as usize];
        if slot.is_none() {
            let mesh = &scene.objects[object as usize].mesh;
            let n = mesh.triangles.len();
            // The solids only serve area lights: a scene without any places none on its moves.
            let area_test = n <= MAX_EXACT_AREA_TRIANGLES && self.areas.iter().any(|a| a.is_some());
            *slot = Some((n <= MAX_EXACT_TRIANGLES).then(|| Exact { bvh: FaceBvh::build(mesh, &NoProgress), solids: if area_test { convex_solids(mesh) } else { None } }));
        }
    }

    /// What `object`'s exact tests need, if [`Self::prepare`]d and not too large.
    pub fn get(&self, object: u32) -> Option<&Exact> {
        self.exact.get(object as usize).and_then(|b| b.as_ref()).and_then(|b| b.as_ref())
    }
}

/// Whether the segment from `a` to `b` (world space) crosses a triangle of `bvh` with the
/// object placed by the transform whose inverse is `to_object`, strictly between its ends
/// (by [`END_MARGIN`]).
pub fn segment_blocked(bvh: &FaceBvh, to_object: &Affine3A, a: Vec3, b: Vec3) -> bool {
    let (oa, ob) = (to_object.transform_point3(a), to_object.transform_point3(b));
    // An affine map keeps the segment's parameter, so the margin means the same here.
    let grow = Vec3::splat(1e-5) * (oa.abs().max(ob.abs()).max_element() + 1.0);
    !bvh.visit(|lo, hi| segment_hits_box(oa, ob, lo - grow, hi + grow), |f| !segment_hits_triangle(oa, ob, f.v))
}

/// Whether the segment `a`–`b` crosses the triangle at a parameter in (`END_MARGIN`,
/// 1 − `END_MARGIN`) (Möller–Trumbore, [`ray_triangle`], with the segment as the ray's
/// direction, so that `t` is the segment's parameter). Edges and corners count as inside.
pub fn segment_hits_triangle(a: Vec3, b: Vec3, [v0, v1, v2]: [Vec3; 3]) -> bool {
    ray_triangle(a, b - a, v0, v1, v2).is_some_and(|t| t > END_MARGIN && t < 1.0 - END_MARGIN)
}

/// How much of an area light an object hides from a point, by itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hidden {
    Nothing,
    Part,
    All,
}

/// An object made of convex closed solids, placed: per solid its world box and its
/// triangles, each with its outward normal.
pub type PlacedSolids = Vec<((DVec3, DVec3), Vec<([DVec3; 3], DVec3)>)>;

/// `solids` (triangles of `mesh`, [`convex_solids`]) placed by `t` (a rigid move or any
/// affine map that keeps the solids' orientation).
pub fn place_solids(mesh: &edgepoint_scene::Mesh, solids: &[Vec<(u32, bool)>], t: &Affine3A) -> PlacedSolids {
    solids
        .iter()
        .map(|ts| {
            let tris: Vec<([DVec3; 3], DVec3)> = ts
                .iter()
                .map(|(f, out)| {
                    let [a, b, c] = mesh.triangle(*f as usize).map(|v| t.transform_point3(v).as_dvec3());
                    let n = (b - a).cross(c - a);
                    ([a, b, c], if *out { n } else { -n })
                })
                .collect();
            let b = tris.iter().flat_map(|t| t.0).fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
            (b, tris)
        })
        .collect()
}

/// The whole of `light` as seen from `p`, before any blocker: the light wholly in front of
/// `p`'s plane parallel to it, so that nothing the shading's tangent plane keeps is left
/// out. `None` when `p` is behind the light.
pub fn whole_light(light: &LightPlane, p: Vec3) -> Option<Visible<'_>> {
    Visible::new(light, p, (-light.n).as_vec3())
}

/// How much of the light of `vis` ([`whole_light`] at the point) the placed `solids` hide by
/// themselves: less each solid's shadow whose box the pyramid from the point to the light
/// does not pass over ([`Visible::solid_shadow`], exactly the union of its triangles'
/// shadows; of its triangles turned toward the point only, when the point is outside the
/// solid's box, since every line from the point that meets the solid enters it through one
/// of those, between the point and the light).
pub fn hidden_by(solids: &PlacedSolids, mut vis: Visible) -> Hidden {
    let hid = occlude_by_solids(solids, &mut vis);
    Hidden::after(hid, &vis)
}

impl Hidden {
    /// What an occlusion that hid something (`hid`) or nothing left of the light: `vis`.
    pub fn after(hid: bool, vis: &Visible) -> Hidden {
        if vis.is_empty() {
            Hidden::All
        } else if hid {
            Hidden::Part
        } else {
            Hidden::Nothing
        }
    }
}

/// Removes from `vis` what the placed `solids` hide of its light (as [`hidden_by`] takes
/// it); returns whether they hid anything.
pub fn occlude_by_solids(solids: &PlacedSolids, vis: &mut Visible) -> bool {
    let mut hid = false;
    let p = vis.pyramid().0;
    for (b, tris) in solids {
        if vis.is_empty() {
            break;
        }
        if vis.passes_over_box(*b) {
            continue;
        }
        // (Inside the solid's box the point may be inside the solid, which every triangle
        // then turns away from: all are taken.)
        let inside = p.cmpge(b.0).all() && p.cmple(b.1).all();
        if let Some(s) = vis.solid_shadow(tris.iter().filter(|(t, n)| inside || n.dot(p - t[0]) > 0.0).map(|(t, _)| *t)) {
            hid |= vis.subtract(&s);
        }
    }
    hid
}

/// How much a move of the placed solids from `from` to `to` can have changed the light of
/// `vis` ([`whole_light`] at the point) that reaches the point, as a fraction of that
/// whole light's irradiance: the irradiance of the part of the light hidden in one place
/// and not in the other (the solids' shadows' symmetric difference). Other blockers can
/// only hide some of that part too, so the change in the point's shading from this light
/// is at most this share of the light's unblocked contribution. `None` when the solids hide
/// nothing in either place, or all of the light in both (nothing changed).
pub fn shift_by(from: &PlacedSolids, to: &PlacedSolids, vis: Visible) -> Option<f64> {
    let whole = vis.irradiance();
    let (mut before, mut after) = (vis.clone(), vis);
    let hid_before = occlude_by_solids(from, &mut before);
    let hid_after = occlude_by_solids(to, &mut after);
    if !hid_before && !hid_after || before.is_empty() && after.is_empty() {
        return None;
    }
    let (eb, ea) = (before.irradiance(), after.irradiance());
    // E(hidden in one place only) = E(L − A) + E(L − B) − 2 E(L − A − B); L − A − B without
    // a third pass where one place hid nothing (it is the other's) or everything (empty).
    let both = if !hid_before {
        ea
    } else if !hid_after {
        eb
    } else if before.is_empty() || after.is_empty() {
        0.0
    } else {
        occlude_by_solids(to, &mut before);
        before.irradiance()
    };
    let differ = (eb + ea - 2.0 * both).max(0.0);
    Some(if whole > 0.0 { (differ / whole).min(1.0) } else { 0.0 })
}

/// The change a move of one object from one place to another made to a point's shadows:
/// the object's exact tests (`None`: none), the inverses of its transforms before and
/// after, its solids placed before and after (area lights), and per light its polygon if it
/// is an area light.
pub struct MoveQuery<'a> {
    pub bvh: Option<&'a FaceBvh>,
    pub before: Affine3A,
    pub after: Affine3A,
    pub solids: Option<(Arc<PlacedSolids>, Arc<PlacedSolids>)>,
    pub lights: &'a [LightBound],
    pub areas: &'a [Option<LightPlane>],
}

impl<'a> MoveQuery<'a> {
    /// The query for a move of the object with mesh `mesh` from `from` to `to`, its solids
    /// placed here; `areas` per light its polygon if it is an area light (none: area lights
    /// get no exact answer). (The session keeps the placed solids between moves:
    /// [`Self::placed`].)
    #[cfg(test)]
    pub fn new(exact: Option<&'a Exact>, mesh: &edgepoint_scene::Mesh, from: &Affine3A, to: &Affine3A, lights: &'a [LightBound], areas: &'a [Option<LightPlane>]) -> Self {
        let solids = exact.and_then(|e| e.solids.as_ref()).map(|s| (Arc::new(place_solids(mesh, s, from)), Arc::new(place_solids(mesh, s, to))));
        MoveQuery::placed(exact, from, to, solids, lights, areas)
    }

    /// [`Self::new`] with the object's solids placed before and after already (`None`: no
    /// exact area-light answer), as the session keeps them between moves.
    pub fn placed(exact: Option<&'a Exact>, from: &Affine3A, to: &Affine3A, solids: Option<(Arc<PlacedSolids>, Arc<PlacedSolids>)>, lights: &'a [LightBound], areas: &'a [Option<LightPlane>]) -> Self {
        MoveQuery { bvh: exact.map(|e| &e.bvh), before: from.inverse(), after: to.inverse(), solids, lights, areas }
    }
}

impl ShadowQuery for MoveQuery<'_> {
    fn change(&self, p: Vec3, light: usize) -> ShadowChange {
        let l = self.lights[light];
        let changed = |c: bool| if c { ShadowChange::Changed } else { ShadowChange::Unchanged };
        if let (Some(bvh), 0.0) = (self.bvh, l.radius) {
            return changed(segment_blocked(bvh, &self.before, p, l.center) != segment_blocked(bvh, &self.after, p, l.center));
        }
        match (&self.solids, self.areas.get(light).and_then(|a| a.as_ref())) {
            (Some((from, to)), Some(area)) => {
                // Behind the light: it lights the point in neither place.
                let Some(vis) = whole_light(area, p) else { return ShadowChange::Unchanged };
                // Hiding nothing in both places or all in both: unchanged. Otherwise shifted
                // by the share of the light hidden in one place only, which a point in the
                // penumbra of an object that keeps moving gains a little of on every move:
                // kept stale while the shifts add up to little (dropped, the penumbra would
                // stay empty while the object moves, filled from its umbra's points).
                match shift_by(from, to, vis) {
                    None => ShadowChange::Unchanged,
                    Some(f) => ShadowChange::Shifted(f as f32),
                }
            }
            _ => ShadowChange::Unknown,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgepoint_scene::geometry::transformed_box;
    use crate::rng::mix64;

    /// A uniform number in [0, 1) from a seed.
    fn uniform(seed: u64) -> f32 {
        (mix64(seed) >> 40) as f32 / (1u64 << 24) as f32
    }

    #[test]
    fn the_hierarchy_test_equals_every_triangle_tested() {
        let scene = edgepoint_scene::builtin::load("cornell-point").unwrap();
        let id = scene.object_id("tallbox").unwrap();
        let mut ms = MoveShadows::new(&scene);
        assert!(ms.get(id).is_none(), "built at the first move only");
        ms.prepare(&scene, id);
        let bvh = &ms.get(id).expect("a box is small").bvh;
        let mesh = &scene.objects[id as usize].mesh;
        let (lo, hi) = mesh.bounds;
        let size = hi - lo;
        let mut blocked = 0;
        for k in 0..4000u64 {
            let r = |j: u64| uniform(k * 8 + j);
            // Ends around the box, some inside it, some far off.
            let a = lo - size + Vec3::new(r(0), r(1), r(2)) * size * 3.0;
            let b = lo - size + Vec3::new(r(3), r(4), r(5)) * size * 3.0;
            let t = Affine3A::from_translation(Vec3::new(r(6) - 0.5, 0.0, r(7) - 0.5) * 0.2);
            let brute = (0..mesh.triangles.len()).any(|f| {
                let [v0, v1, v2] = mesh.triangle(f);
                segment_hits_triangle(a, b, [t.transform_point3(v0), t.transform_point3(v1), t.transform_point3(v2)])
            });
            assert_eq!(segment_blocked(bvh, &t.inverse(), a, b), brute, "segment {a} {b}");
            blocked += usize::from(brute);
        }
        assert!(blocked > 400 && blocked < 3600, "{blocked} of 4000 blocked: the cases cover both answers");
    }

    #[test]
    fn crossing_a_triangle_against_closed_forms() {
        let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let through = |x: f32, y: f32| segment_hits_triangle(Vec3::new(x, y, -1.0), Vec3::new(x, y, 1.0), tri);
        assert!(through(0.25, 0.25));
        assert!(!through(0.6, 0.6), "beyond the hypotenuse");
        assert!(!through(-0.01, 0.5));
        // Ends: a segment ending on the plane does not cross it, one ending past it does.
        assert!(!segment_hits_triangle(Vec3::new(0.2, 0.2, 0.0), Vec3::new(0.2, 0.2, 1.0), tri));
        assert!(segment_hits_triangle(Vec3::new(0.2, 0.2, -0.01), Vec3::new(0.2, 0.2, 1.0), tri));
        // Parallel to the plane: never.
        assert!(!segment_hits_triangle(Vec3::new(-1.0, 0.2, 0.0), Vec3::new(1.0, 0.2, 0.0), tri));
    }

    #[test]
    fn a_move_changes_the_shadow_exactly_where_one_place_blocks_and_the_other_not() {
        // A unit-square blocker at height 1 under a point light at height 2, moved by 0.5
        // along X: on the floor (height 0) its shadow is the square scaled by 2 about the
        // light's foot, so x in [-1, 1] before and [0, 2] after (along z in [-1, 1]).
        let v = [Vec3::new(-0.5, 1.0, -0.5), Vec3::new(0.5, 1.0, -0.5), Vec3::new(0.5, 1.0, 0.5), Vec3::new(-0.5, 1.0, 0.5)];
        let mesh = edgepoint_scene::Mesh::from_triangles(v.to_vec(), vec![[0, 1, 2], [0, 2, 3]], &NoProgress);
        let exact = Exact { bvh: FaceBvh::build(&mesh, &NoProgress), solids: None };
        let lights = [LightBound { center: Vec3::new(0.0, 2.0, 0.0), radius: 0.0 }, LightBound { center: Vec3::new(0.0, 2.0, 0.0), radius: 0.1 }];
        let (from, to) = (Affine3A::IDENTITY, Affine3A::from_translation(Vec3::new(0.5, 0.0, 0.0)));
        let q = MoveQuery::new(Some(&exact), &mesh, &from, &to, &lights, &[]);
        for k in 0..=60 {
            let x = -1.5 + k as f32 * 0.0625 + 0.01;
            let want = if (x > -1.0 && x < 0.0) || (x > 1.0 && x < 2.0) { ShadowChange::Changed } else { ShadowChange::Unchanged };
            assert_eq!(q.change(Vec3::new(x, 0.0, 0.3), 0), want, "x = {x}");
            assert_eq!(q.change(Vec3::new(x, 0.0, 0.3), 1), ShadowChange::Unknown, "an area light");
        }
        let none = MoveQuery::new(None, &mesh, &from, &to, &lights, &[]);
        assert_eq!(none.change(Vec3::new(-0.5, 0.0, 0.0), 0), ShadowChange::Unknown, "no hierarchy");
    }

    /// [`shift_by`] against the same measure from every triangle occluding the light one by
    /// one (the irradiance of the light hidden in one place only, over the whole light's):
    /// `cornell`'s tall box moved at random (turned about Y, slid up to a sixth of the room)
    /// from random places, random points around and under it.
    #[test]
    fn the_shift_is_the_light_hidden_in_one_place_only() {
        let scene = edgepoint_scene::builtin::load("cornell").unwrap();
        let id = scene.object_id("tallbox").unwrap() as usize;
        let mesh = &scene.objects[id].mesh;
        let solids = convex_solids(mesh).expect("a box");
        let ms = MoveShadows::new(&scene);
        let plane = ms.areas().iter().flatten().next().expect("cornell's light");
        let (lo, hi) = scene.bounds();
        let size = hi - lo;
        let base = scene.objects[id].transform;
        let place = |r: &dyn Fn(u64) -> f32, j: u64| Affine3A::from_translation(Vec3::new(r(j) - 0.5, 0.0, r(j + 1) - 0.5) * size / 6.0) * base * Affine3A::from_rotation_y(r(j + 2));
        let left = |p: Vec3, ts: &[&Affine3A]| {
            whole_light(plane, p).map_or(0.0, |mut v| {
                for t in ts {
                    for f in 0..mesh.triangles.len() {
                        v.occlude(mesh.triangle(f).map(|x| t.transform_point3(x).as_dvec3()));
                    }
                }
                v.irradiance()
            })
        };
        let (mut none, mut some) = (0, 0);
        for k in 0..2000u64 {
            let r = |j: u64| uniform(k * 16 + j);
            let (from, to) = (place(&r, 0), place(&r, 3));
            let (blo, bhi) = transformed_box(&from, mesh.bounds);
            let c = (blo + bhi) * 0.5;
            let p = Vec3::new(c.x + (r(6) - 0.5) * 2.0 * size.x / 3.0, lo.y + r(7) * (bhi.y - lo.y), c.z + (r(8) - 0.5) * 2.0 * size.z / 3.0);
            let Some(vis) = whole_light(plane, p) else { continue };
            let whole = vis.irradiance();
            let got = shift_by(&place_solids(mesh, &solids, &from), &place_solids(mesh, &solids, &to), vis);
            let (eb, ea, eab) = (left(p, &[&from]), left(p, &[&to]), left(p, &[&from, &to]));
            let want = (eb + ea - 2.0 * eab) / whole;
            match got {
                None => {
                    // Nothing hidden in either place, or everything in both.
                    assert!(want.abs() < 1e-9 && ((eb - whole).abs() < 1e-9 * whole || eb < 1e-9 * whole), "point {p}, move {k}: none, but {want}");
                    none += 1;
                }
                Some(f) => {
                    assert!((f - want.min(1.0)).abs() < 1e-9, "point {p}, move {k}: {f} against {want}");
                    some += usize::from(f > 0.01);
                }
            }
        }
        eprintln!("unchanged {none}, shifted by over 1 % {some}");
        assert!(none > 100 && some > 100, "unchanged {none}, shifted {some}: both cases covered");
    }

    /// [`hidden_by`] against the light seen from the point occluded by every triangle of the
    /// object (no solids): `cornell`'s tall box (one solid, standing on the floor) and
    /// `rooms`' `chair4a` (six boxes, the back welded to the seat along an edge) placed at
    /// random (turned about Y, slid up to a third of the room or 1.5 m), random points
    /// around and under them from the floor up to their tops, each scene's lights.
    #[test]
    fn hidden_by_equals_every_triangle_occluding_the_light() {
        for (name, object, slide) in [("cornell", "tallbox", None), ("rooms", "chair4a", Some(1.5f32))] {
            let scene = edgepoint_scene::builtin::load(name).unwrap();
            let id = scene.object_id(object).unwrap() as usize;
            let mesh = &scene.objects[id].mesh;
            let solids = convex_solids(mesh).expect("made of convex solids");
            let ms = MoveShadows::new(&scene);
            let planes: Vec<&LightPlane> = ms.areas().iter().flatten().collect();
            let (lo, hi) = scene.bounds();
            let size = hi - lo;
            let base = scene.objects[id].transform;
            let mut counts = [0usize; 3];
            for k in 0..3000u64 {
                let r = |j: u64| uniform(k * 16 + j);
                let shift = slide.map_or(size / 3.0, Vec3::splat);
                let t = Affine3A::from_translation(Vec3::new(r(0) - 0.5, 0.0, r(1) - 0.5) * shift) * base * Affine3A::from_rotation_y(r(2) * 6.0);
                let (blo, bhi) = transformed_box(&t, mesh.bounds);
                let c = (blo + bhi) * 0.5;
                let p = Vec3::new(c.x + (r(3) - 0.5) * 3.0 * (bhi.x - blo.x), lo.y + r(4) * (bhi.y - lo.y), c.z + (r(5) - 0.5) * 3.0 * (bhi.z - blo.z));
                let plane = planes[(r(6) * planes.len() as f32) as usize % planes.len()];
                let got = whole_light(plane, p).map_or(Hidden::Nothing, |v| hidden_by(&place_solids(mesh, &solids, &t), v));
                let want = whole_light(plane, p).map_or(Hidden::Nothing, |mut v| {
                    let mut hid = false;
                    for f in 0..mesh.triangles.len() {
                        hid |= v.occlude(mesh.triangle(f).map(|x| t.transform_point3(x).as_dvec3()));
                    }
                    Hidden::after(hid, &v)
                });
                assert_eq!(got, want, "{name}: point {p}, move {k}");
                counts[want as usize] += 1;
            }
            eprintln!("{name}: nothing / part / all: {counts:?}");
            assert!(counts.iter().all(|c| *c > 50), "{name}: nothing / part / all: {counts:?}");
        }
    }
}
