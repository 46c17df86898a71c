//! Equal-area surface elements for the `hybrid` shader's virtual point lights (paper 004 §3:
//! "we tessellate polygons in the scene into elements of equal area for the indirect
//! lighting pass").
//!
//! The target area is t = (area of the scene's diffusely reflecting triangles) / `target`,
//! in world space under one epoch's object transforms. A triangle of area A ≥ t is cut into
//! n² congruent triangles, n = ⌈√(A/t)⌉ (each of area A/n², between t/4 and t). A triangle
//! smaller than t (scanned meshes have millions) is kept with probability A/t and then
//! stands for area t — Russian roulette on area, so the elements' expected total area is the
//! scene's and their count stays near `target` (at most about 4 × `target`) however finely a
//! mesh is tessellated. The choice is a hash of (object, triangle), so the same scene and
//! transforms always give the same elements.
//!
//! Only surfaces with a diffuse part reflect light into VPLs: the Lambertian part's albedo
//! seen along the normal (Lambert: its albedo; plastic: its base under the coat's
//! transmittance); metals and glass make none (what they reflect is caustics, which paper
//! 004 does not treat either).
use crate::rng::Rng;
use edgepoint_scene::material::Scatter;
use edgepoint_scene::Scene;
use glam::{Affine3A, Vec3};

/// Seed of the small triangles' keep-or-drop choice (fixed: elements depend on the scene and
/// the transforms only, never on a batch's seed).
const KEEP_SEED: u64 = 0x656c_656d_656e_7473;

/// One element: a triangle in world space on one object.
#[derive(Debug, Clone, PartialEq)]
pub struct Element {
    pub tri: [Vec3; 3],
    /// Unit face normal of the mesh winding, world space.
    pub normal: Vec3,
    /// The area it stands for (its own, or t for a small triangle kept by roulette).
    pub area: f32,
    /// Diffuse reflectance.
    pub albedo: Vec3,
    pub object: u32,
    /// Reflects on the side opposite `normal` too.
    pub two_sided: bool,
}

impl Element {
    /// The point at uniform (u, v) ∈ [0, 1)² (uniform in area).
    #[inline]
    pub fn point(&self, u: f32, v: f32) -> Vec3 {
        let s = u.sqrt();
        let [a, b, c] = self.tri;
        a * (1.0 - s) + b * (s * (1.0 - v)) + c * (s * v)
    }

    pub fn centroid(&self) -> Vec3 {
        (self.tri[0] + self.tri[1] + self.tri[2]) / 3.0
    }
}

/// The diffuse reflectance of triangle `tri` of object `o` at barycentric point `bary`.
fn albedo(o: &edgepoint_scene::Object, tri: usize, bary: Vec3) -> Vec3 {
    let m = &o.material;
    let base = match (&m.texture, &o.mesh.corners.uvs) {
        (Some(tex), Some(uvs)) if tri < uvs.len() => {
            let t = uvs[tri];
            m.diffuse * tex.sample(t[0] * bary.x + t[1] * bary.y + t[2] * bary.z)
        }
        (Some(tex), _) => m.diffuse * tex.sample(glam::Vec2::ZERO),
        (None, _) => m.diffuse,
    };
    m.bsdf.at(base).diffuse_albedo(Vec3::Z)
}

/// The area t every element stands for (module doc): the diffusely reflecting area of
/// `scene` under `transforms`, over `target`.
pub(crate) fn element_area(scene: &Scene, transforms: &[Affine3A], target: u32) -> f32 {
    let mut total = 0.0f64;
    for (oi, o) in scene.objects.iter().enumerate() {
        // Diffusely reflecting objects (decided on the untextured base: a texture only scales it).
        if o.material.bsdf.at(Vec3::ONE).diffuse_albedo(Vec3::Z).max_element() > 0.0 {
            let tr = transforms.get(oi).unwrap_or(&o.transform);
            total += (0..o.mesh.triangles.len())
                .map(|ti| {
                    let [a, b, c] = o.mesh.triangle(ti).map(|p| tr.transform_point3(p));
                    ((b - a).cross(c - a).length() * 0.5) as f64
                })
                .sum::<f64>();
        }
    }
    (total / target.max(1) as f64) as f32
}

/// The elements of `scene` under `transforms` (one per object), about `target` of them.
pub fn tessellate(scene: &Scene, transforms: &[Affine3A], target: u32) -> Vec<Element> {
    let world = |oi: usize, ti: usize| {
        let o = &scene.objects[oi];
        let t = transforms.get(oi).unwrap_or(&o.transform);
        o.mesh.triangle(ti).map(|p| t.transform_point3(p))
    };
    let area = |[a, b, c]: [Vec3; 3]| (b - a).cross(c - a).length() * 0.5;
    // Diffusely reflecting objects (decided on the untextured base: a texture only scales it).
    let reflects: Vec<bool> = scene.objects.iter().map(|o| o.material.bsdf.at(Vec3::ONE).diffuse_albedo(Vec3::Z).max_element() > 0.0).collect();
    let t = element_area(scene, transforms, target);
    if !(t > 0.0 && t.is_finite()) {
        return Vec::new();
    }
    let mut out = Vec::new();
    for (oi, o) in scene.objects.iter().enumerate() {
        if !reflects[oi] {
            continue;
        }
        let tr = transforms.get(oi).unwrap_or(&o.transform);
        let to_world = tr.matrix3.inverse().transpose();
        for ti in 0..o.mesh.triangles.len() {
            let w = world(oi, ti);
            let a = area(w);
            let normal = (to_world * o.mesh.face_normals[ti]).normalize_or_zero();
            if a.is_nan() || a <= 0.0 || normal == Vec3::ZERO {
                continue;
            }
            let mk = |tri: [Vec3; 3], area: f32, bary: Vec3| Element { tri, normal, area, albedo: albedo(o, ti, bary), object: oi as u32, two_sided: o.material.two_sided };
            if a < t {
                let mut rng = Rng::new(KEEP_SEED, ((oi as u64) << 32) | ti as u64);
                if rng.next_f32() < a / t {
                    out.push(mk(w, t, Vec3::splat(1.0 / 3.0)));
                }
                continue;
            }
            let n = (a / t).sqrt().ceil().max(1.0) as u32;
            let sub = a / (n * n) as f32;
            let nf = n as f32;
            // Barycentric grid point (i, j): a + (b − a) i/n + (c − a) j/n.
            let bary = |i: u32, j: u32| Vec3::new(1.0 - (i + j) as f32 / nf, i as f32 / nf, j as f32 / nf);
            let at = |b: Vec3| w[0] * b.x + w[1] * b.y + w[2] * b.z;
            for i in 0..n {
                for j in 0..n - i {
                    let corners = [bary(i, j), bary(i + 1, j), bary(i, j + 1)];
                    out.push(mk(corners.map(at), sub, (corners[0] + corners[1] + corners[2]) / 3.0));
                    if j + 1 < n - i {
                        let corners = [bary(i + 1, j), bary(i + 1, j + 1), bary(i, j + 1)];
                        out.push(mk(corners.map(at), sub, (corners[0] + corners[1] + corners[2]) / 3.0));
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `tessellate`'s rule for the objects it cuts into elements.
    fn reflects(o: &edgepoint_scene::Object) -> bool {
        o.material.bsdf.at(Vec3::ONE).diffuse_albedo(Vec3::Z).max_element() > 0.0
    }

    #[test]
    fn elements_cover_the_diffuse_area_in_pieces_of_about_equal_area() {
        let s = edgepoint_scene::builtin::load("cornell").unwrap();
        let tf: Vec<Affine3A> = s.objects.iter().map(|o| o.transform).collect();
        let total: f32 = s.objects.iter().filter(|o| reflects(o)).map(|o| o.mesh.area()).sum();
        let smallest = s.objects.iter().filter(|o| reflects(o)).flat_map(|o| (0..o.mesh.triangles.len()).map(|ti| {
                let [a, b, c] = o.mesh.triangle(ti);
                (b - a).cross(c - a).length() * 0.5
            }))
            .fold(f32::INFINITY, f32::min);
        let mut exact = 0;
        for target in [64u32, 1000, 5000] {
            let els = tessellate(&s, &tf, target);
            let t = element_area(&s, &tf, target);
            let sum: f32 = els.iter().map(|e| e.area).sum();
            if smallest >= t {
                // Every triangle at least t: exact subdivision, no roulette.
                assert!((sum - total).abs() < 1e-3 * total, "{target}: {sum} vs {total}");
                assert!(els.iter().all(|e| e.area <= t * 1.0001 && e.area > t / 4.0 - 1e-9), "{target}");
                assert!(els.len() as u32 >= target && (els.len() as u32) < 4 * target, "{target}: {}", els.len());
                for e in &els {
                    let [a, b, c] = e.tri;
                    assert!(((b - a).cross(c - a).length() * 0.5 - e.area).abs() < 1e-4 * e.area.max(1e-6) + 1e-9);
                }
                exact += 1;
            } else {
                // Small triangles (the luminaire's) kept by roulette stand for t each: the
                // total holds in expectation.
                assert!((sum - total).abs() < 0.15 * total, "{target}: {sum} vs {total}");
                assert!(els.iter().all(|e| e.area <= t * 1.0001), "{target}");
            }
            for e in &els {
                let [a, b, c] = e.tri;
                assert!(((b - a).cross(c - a).normalize().dot(e.normal) - 1.0).abs() < 1e-3, "winding kept");
            }
        }
        assert!(exact >= 1, "at least one target subdivides exactly (smallest triangle {smallest})");
    }

    #[test]
    fn small_triangles_are_kept_by_area_roulette_and_moved_objects_move_their_elements() {
        // A finely tessellated sphere (many triangles far below t) and a big floor.
        let mut s = edgepoint_scene::builtin::load("materials").unwrap();
        s.objects.truncate(2);
        let tf: Vec<Affine3A> = s.objects.iter().map(|o| o.transform).collect();
        let target = 200;
        let els = tessellate(&s, &tf, target);
        let ball: Vec<&Element> = els.iter().filter(|e| e.object == 1).collect();
        let ball_area = s.objects[1].mesh.area();
        let t = element_area(&s, &tf, target);
        assert!(ball_area / (s.objects[1].mesh.triangles.len() as f32) < t / 20.0, "the sphere's triangles are small");
        // Expected count ball_area / t; a binomial count: within 5 standard deviations.
        let expect = ball_area / t;
        assert!((ball.len() as f32 - expect).abs() < 5.0 * expect.sqrt() + 1.0, "{} vs {expect}", ball.len());
        assert!(ball.iter().all(|e| e.area == t));
        assert_eq!(els, tessellate(&s, &tf, target), "deterministic");
        let mut moved = tf.clone();
        moved[1] = Affine3A::from_translation(Vec3::new(0.0, 2.0, 0.0)) * tf[1];
        let els2 = tessellate(&s, &moved, target);
        let b2: Vec<&Element> = els2.iter().filter(|e| e.object == 1).collect();
        assert_eq!(b2.len(), ball.len());
        for (a, b) in ball.iter().zip(&b2) {
            assert!((b.centroid() - a.centroid() - Vec3::new(0.0, 2.0, 0.0)).length() < 1e-5);
        }
        // Metals and glass make no elements.
        let mut glass = s.clone();
        glass.objects[1].material.bsdf = edgepoint_scene::Bsdf::Dielectric { ior: 1.5, roughness: 0.0 };
        assert!(tessellate(&glass, &tf, target).iter().all(|e| e.object == 0));
    }
}
