//! Whether a move changed a point's shadow from a point light, exactly (the session's
//! [`ShadowQuery`] for [`crate::render_cache::reshadow`], and the same test for samples
//! shaded before moves that arrive after them).
//!
//! A point light's shadow at `p` from an object is the segment from `p` to the light
//! meeting one of the object's triangles. A rigid move leaves the triangles as they are in
//! object space, so the test runs there, against the object's face hierarchy
//! ([`FaceBvh`], built once per object at its first move), with the segment taken into
//! object space by the inverse of each transform. Area lights get no exact answer
//! ([`ShadowChange::Unknown`]): their points are marked stale as before.
use crate::edges::face_bvh::FaceBvh;
use crate::render_cache::reshadow::{ShadowChange, ShadowQuery};
use crate::render_cache::{segment_hits_box, LightBound};
use edgepoint_scene::geometry::ray_triangle;
use edgepoint_scene::{NoProgress, Scene};
use glam::{Affine3A, Vec3};

/// Objects with more triangles get no exact test (their moves mark points stale, as
/// before): the hierarchy is built on the frame thread at the object's first move, which
/// must stay a few milliseconds.
pub const MAX_EXACT_TRIANGLES: usize = 1 << 16;

/// A shadow ray's ends are left out by this fraction of its length: a receiver touching the
/// object (the floor under a box) is not shadowed by the face it touches, and the light
/// itself is not a blocker.
const END_MARGIN: f32 = 1e-4;

/// Per object, its face hierarchy once it has moved (`None` inside: too large).
pub struct MoveShadows {
    bvhs: Vec<Option<Option<FaceBvh>>>,
}

impl MoveShadows {
    pub fn new(objects: usize) -> Self {
        MoveShadows { bvhs: (0..objects).map(|_| None).collect() }
    }

    /// Builds `object`'s hierarchy if it has none yet (at most once per object).
    pub fn prepare(&mut self, scene: &Scene, object: u32) {
        let slot = &mut self.bvhs[object as usize];
        if slot.is_none() {
            let mesh = &scene.objects[object as usize].mesh;
            *slot = Some((mesh.triangles.len() <= MAX_EXACT_TRIANGLES).then(|| FaceBvh::build(mesh, &NoProgress)));
        }
    }

    /// `object`'s hierarchy, if [`Self::prepare`]d and not too large.
    pub fn get(&self, object: u32) -> Option<&FaceBvh> {
        self.bvhs.get(object as usize).and_then(|b| b.as_ref()).and_then(|b| b.as_ref())
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

/// The change a move of one object from one place to another made to a point's shadows: the
/// object's hierarchy (`None`: no exact test) and the inverses of its transforms before and
/// after.
pub struct MoveQuery<'a> {
    pub bvh: Option<&'a FaceBvh>,
    pub before: Affine3A,
    pub after: Affine3A,
    pub lights: &'a [LightBound],
}

impl<'a> MoveQuery<'a> {
    /// The query for a move from `from` to `to`.
    pub fn new(bvh: Option<&'a FaceBvh>, from: &Affine3A, to: &Affine3A, lights: &'a [LightBound]) -> Self {
        MoveQuery { bvh, before: from.inverse(), after: to.inverse(), lights }
    }
}

impl ShadowQuery for MoveQuery<'_> {
    fn change(&self, p: Vec3, light: usize) -> ShadowChange {
        let l = self.lights[light];
        match self.bvh {
            Some(bvh) if l.radius == 0.0 => {
                if segment_blocked(bvh, &self.before, p, l.center) != segment_blocked(bvh, &self.after, p, l.center) {
                    ShadowChange::Changed
                } else {
                    ShadowChange::Unchanged
                }
            }
            _ => ShadowChange::Unknown,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::mix64;

    /// A uniform number in [0, 1) from a seed.
    fn uniform(seed: u64) -> f32 {
        (mix64(seed) >> 40) as f32 / (1u64 << 24) as f32
    }

    #[test]
    fn the_hierarchy_test_equals_every_triangle_tested() {
        let scene = edgepoint_scene::builtin::load("cornell-point").unwrap();
        let id = scene.object_id("tallbox").unwrap();
        let mut ms = MoveShadows::new(scene.objects.len());
        assert!(ms.get(id).is_none(), "built at the first move only");
        ms.prepare(&scene, id);
        let bvh = ms.get(id).expect("a box is small");
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
        let bvh = FaceBvh::build(&mesh, &NoProgress);
        let lights = [LightBound { center: Vec3::new(0.0, 2.0, 0.0), radius: 0.0 }, LightBound { center: Vec3::new(0.0, 2.0, 0.0), radius: 0.1 }];
        let (from, to) = (Affine3A::IDENTITY, Affine3A::from_translation(Vec3::new(0.5, 0.0, 0.0)));
        let q = MoveQuery::new(Some(&bvh), &from, &to, &lights);
        for k in 0..=60 {
            let x = -1.5 + k as f32 * 0.0625 + 0.01;
            let want = if (x > -1.0 && x < 0.0) || (x > 1.0 && x < 2.0) { ShadowChange::Changed } else { ShadowChange::Unchanged };
            assert_eq!(q.change(Vec3::new(x, 0.0, 0.3), 0), want, "x = {x}");
            assert_eq!(q.change(Vec3::new(x, 0.0, 0.3), 1), ShadowChange::Unknown, "an area light");
        }
        let none = MoveQuery::new(None, &from, &to, &lights);
        assert_eq!(none.change(Vec3::new(-0.5, 0.0, 0.0), 0), ShadowChange::Unknown, "no hierarchy");
    }
}
