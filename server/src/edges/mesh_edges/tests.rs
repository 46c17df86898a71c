//! The mesh's shadow edges against ray-traced visibility: on the lit side of a penumbral
//! edge every ray to the light passes, on the umbra side of an umbral edge none does, and
//! on the penumbra side the exact irradiance with every triangle of the scene as a blocker
//! (not the mesh's shaft list) lies strictly between none and all of the light.
use super::*;
use crate::dmesh::grid::Grid;
use crate::dmesh::{area_lights, DiscontinuityMesh, GRID_TRIANGLES_PER_VOXEL};
use crate::rng::Rng;
use edgepoint_scene::backprojection::irradiance_with_blockers;

/// Whether segment `p → q` (excluding its ends) crosses triangle `t` (f64 Möller–Trumbore).
fn blocks(p: DVec3, q: DVec3, t: [DVec3; 3]) -> bool {
    let d = q - p;
    let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
    let h = d.cross(e2);
    let det = e1.dot(h);
    if det.abs() < 1e-300 {
        return false;
    }
    let f = 1.0 / det;
    let s = p - t[0];
    let u = f * s.dot(h);
    if !(0.0..=1.0).contains(&u) {
        return false;
    }
    let qv = s.cross(e1);
    let v = f * d.dot(qv);
    if v < 0.0 || u + v > 1.0 {
        return false;
    }
    let tt = f * e2.dot(qv);
    tt > 1e-9 && tt < 1.0 - 1e-6
}

/// Of `n` × `n` stratified rays from `p` to points of the light, per triangle of the light's
/// fan, how many pass every triangle of `g`; only rays to the part of the light above the
/// receiver's plane (normal `normal`) count: the part below gives no light, and the mesh
/// clips it away.
fn rays_passing(g: &Geometry, light: &LightPlane, p: DVec3, normal: DVec3, n: usize, rng: &mut Rng) -> (usize, usize) {
    let c: Vec<DVec3> = light.corners.iter().map(|q| light.lift(*q)).collect();
    let (mut pass, mut total) = (0, 0);
    for k in 1..c.len() - 1 {
        let (a, b, d) = (c[0], c[k], c[k + 1]);
        for i in 0..n {
            for j in 0..n {
                let (mut u, mut v) = ((i as f64 + rng.f64()) / n as f64, (j as f64 + rng.f64()) / n as f64);
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                // Pulled toward the light's centre a little: its own fixture's sides stay out.
                let x = a + (b - a) * u + (d - a) * v;
                let x = x + (c.iter().copied().sum::<DVec3>() / c.len() as f64 - x) * 1e-3;
                if (x - p).dot(normal) <= 0.0 {
                    continue;
                }
                total += 1;
                if (0..g.tris.len() as u32).all(|t| !blocks(p, x, g.tri(t))) {
                    pass += 1;
                }
            }
        }
    }
    (pass, total)
}

/// Checks both sides of every mesh edge of `mesh` on `g` that the EPI is given or that
/// separates two kinds of lighting; returns how many sides were checked.
fn check(g: &Geometry, mesh: &DiscontinuityMesh, rng: &mut Rng) -> usize {
    let all: Vec<[Vec3; 3]> = (0..g.tris.len() as u32).map(|t| g.tri(t).map(|p| p.as_vec3())).collect();
    let mut checked = 0;
    let mut hit = Vec::new();
    for (l, light) in mesh.lights.iter().enumerate() {
        for m in mesh.meshes[l].iter().flatten() {
            if m.umbra {
                continue;
            }
            let (a, r) = (&m.arrangement, &m.receiver);
            for (e, (ends, gen)) in a.edges.iter().enumerate() {
                if gen.is_none() {
                    continue;
                }
                let Some(s) = sides(r, a.vertices[ends[0] as usize], a.vertices[ends[1] as usize]) else { continue };
                let lit = s.map(|q| lighting_at(m, g, light, q, &mut hit));
                if lit[0] == lit[1] {
                    continue;
                }
                for (q, lighting) in s.into_iter().zip(lit) {
                    let p = r.to3(q) + r.n * (10.0 * r.tol);
                    let label = format!("light {l}, receiver {}, edge {e}, {lighting:?} side (other {:?}) at {p}", r.tri, lit);
                    let (xp, n) = (p.as_vec3(), r.n.as_vec3());
                    match lighting {
                        Lighting::Lit => {
                            let (pass, total) = rays_passing(g, light, p, r.n, 8, rng);
                            assert_eq!(pass, total, "{label}: the whole light must be visible");
                        }
                        Lighting::Umbra => {
                            let (pass, total) = rays_passing(g, light, p, r.n, 8, rng);
                            assert_eq!(pass, 0, "{label}: none of the light may be visible ({pass} of {total} rays pass)");
                        }
                        Lighting::Penumbra => {
                            // Exact, with every triangle of the scene as a blocker: strictly
                            // between none and all of the light. Right beside an extremal
                            // edge the sliver seen or hidden is about 10⁻¹² of the light, at
                            // the clipping's rounding, so the point moves away from the edge
                            // (10× at a time, while it stays in a penumbra and the
                            // triangle) until the sliver is clear of it.
                            let mid = 0.5 * (a.vertices[ends[0] as usize] + a.vertices[ends[1] as usize]);
                            let mut found = None;
                            for k in [1.0, 10.0, 100.0, 1e3, 1e4] {
                                let qk = mid + (q - mid) * k;
                                if !r.contains(qk) || lighting_at(m, g, light, qk, &mut hit) != Lighting::Penumbra {
                                    break;
                                }
                                let pk = (r.to3(qk) + r.n * (10.0 * r.tol)).as_vec3();
                                let full = irradiance_with_blockers(light, pk, n, []);
                                let e = irradiance_with_blockers(light, pk, n, all.iter().copied());
                                if e > 0.0 && e < full {
                                    found = Some(k);
                                    break;
                                }
                            }
                            assert!(found.is_some(), "{label}: no point of this penumbra side sees part of the light (every triangle as a blocker)");
                            let _ = xp;
                        }
                    }
                    checked += 1;
                }
            }
        }
    }
    checked
}

#[test]
fn extremal_edges_separate_what_rays_see_of_the_light() {
    let mut rng = Rng::new(11);
    let mut checked = 0;
    for (g, lights) in crate::dmesh::tests::random_scenes_and_cornell(&mut rng, 6) {
        let grid = Grid::build(&g, GRID_TRIANGLES_PER_VOXEL);
        let mesh = DiscontinuityMesh::compute(&g, &grid, &lights);
        checked += check(&g, &mesh, &mut rng);
    }
    assert!(checked > 50, "only {checked} sides checked");
}

#[test]
fn cornell_gives_penumbral_and_umbral_edges_on_its_receivers() {
    let scene = edgepoint_scene::builtin::load("cornell").unwrap();
    let g = Geometry::from_scene(&scene);
    let grid = Grid::build(&g, GRID_TRIANGLES_PER_VOXEL);
    let mesh = DiscontinuityMesh::compute(&g, &grid, &area_lights(&scene));
    let mut out = Vec::new();
    let c = mesh_shadow_edges(&mesh, &g, &mut out);
    assert_eq!(out.len(), c.penumbral + c.umbral + c.hard + c.interior_steep);
    assert!(c.penumbral > 0 && c.umbral > 0, "{c:?}");
    for MeshShadowEdge { edge: e, penumbra: p, .. } in &out {
        // On a receiver's object, with a penumbra across (not along) it.
        assert!(g.object.contains(&e.object), "{e:?}: not on an object");
        let d = (e.b - e.a).normalize_or_zero();
        for v in p {
            assert!(v.is_finite() && v.dot(d).abs() <= 1e-4 * v.length().max(1e-12), "{e:?}: penumbra {v} not across");
        }
        assert!(matches!(e.kind, EdgeKind::ShadowPenumbral | EdgeKind::ShadowUmbral));
    }
    // The boxes' shadows on the floor are bounded on both sides.
    let floor = scene.object_id("floor").unwrap();
    let on_floor = |k: EdgeKind| out.iter().filter(|m| m.edge.object == floor && m.edge.kind == k).count();
    assert!(on_floor(EdgeKind::ShadowPenumbral) > 0 && on_floor(EdgeKind::ShadowUmbral) > 0);
}

/// A floor, plates far wider than it at the given heights covering `x < edge` (`left`) or
/// `x > edge`, and a light: the geometry of the closed-form tests below.
fn plates(plates: &[(f64, f64, bool)], light: &[Vec3]) -> (Geometry, LightPlane) {
    let mut objects = vec![(vec![DVec3::new(-3.0, 0.0, -3.0), DVec3::new(3.0, 0.0, -3.0), DVec3::new(3.0, 0.0, 3.0), DVec3::new(-3.0, 0.0, 3.0)], vec![[0, 1, 2], [0, 2, 3]])];
    for &(y, edge, left) in plates {
        let (x0, x1) = if left { (-6.0, edge) } else { (edge, 6.0) };
        objects.push((vec![DVec3::new(x0, y, -6.0), DVec3::new(x1, y, -6.0), DVec3::new(x1, y, 6.0), DVec3::new(x0, y, 6.0)], vec![[0, 1, 2], [0, 2, 3]]));
    }
    let light = LightPlane::new(light).unwrap();
    assert!(light.n.y < 0.0, "the light must face the floor");
    (Geometry::from_objects(&objects), light)
}

fn counts_of(g: &Geometry, light: LightPlane) -> MeshEdgeCounts {
    let grid = Grid::build(g, GRID_TRIANGLES_PER_VOXEL);
    let mesh = DiscontinuityMesh::compute(g, &grid, &[light]);
    mesh_shadow_edges(&mesh, g, &mut Vec::new())
}

/// Behind one straight blocker edge the visible part of a square light turned by 45° is the
/// diamond cut by a moving line: its area is piecewise quadratic with a continuous slope
/// (a D2 event where the cut passes the middle corners), so the interior edge there is not
/// steep.
#[test]
fn interior_edges_of_a_smooth_ramp_are_not_steep() {
    let r = 0.5 * std::f32::consts::SQRT_2;
    let diamond = [Vec3::new(-r, 2.0, 0.0), Vec3::new(0.0, 2.0, -r), Vec3::new(r, 2.0, 0.0), Vec3::new(0.0, 2.0, r)];
    let (g, light) = plates(&[(1.0, 0.0, true)], &diamond);
    let c = counts_of(&g, light);
    assert!(c.penumbral > 0 && c.umbral > 0 && c.interior_smooth > 0, "{c:?}");
    assert_eq!(c.interior_steep, 0, "{c:?}");
}

/// Two plates hiding the light from opposite sides: where the lower one's penumbra starts
/// inside the upper one's (floor x = 0.1, closed form: the visible interval of the light
/// [−X, 0.5] turns into [−X, 0.8 − 3X]), the slope of the visible width jumps from +1 to
/// −2, three times the penumbra's mean slope: that interior edge is steep.
#[test]
fn an_interior_edge_where_another_shadow_starts_is_steep() {
    let square = [Vec3::new(-0.5, 2.0, -0.5), Vec3::new(0.5, 2.0, -0.5), Vec3::new(0.5, 2.0, 0.5), Vec3::new(-0.5, 2.0, 0.5)];
    let (g, light) = plates(&[(1.0, 0.0, true), (0.5, 0.2, false)], &square);
    let c = counts_of(&g, light);
    assert!(c.interior_steep > 0, "{c:?}");
}

/// After a move, the receivers the update replaced make their edges again keeping the
/// decisions the moved object cannot have changed ([`receivers_shadow_edges`] with `reuse`):
/// the same edges, in the same order, as making every one afresh, over random scenes (and
/// `cornell`) and random moves of every object; and decisions are kept.
#[test]
fn edges_kept_across_a_move_equal_edges_made_afresh() {
    let mut rng = Rng::new(23);
    let (mut kept, mut made) = (0, 0);
    for (mut g, lights) in crate::dmesh::tests::random_scenes_and_cornell(&mut rng, 8) {
        let mut grid = Grid::build(&g, GRID_TRIANGLES_PER_VOXEL);
        let mut mesh = DiscontinuityMesh::compute(&g, &grid, &lights);
        let objects = g.tri_start.len() as u32;
        let size = (g.bounds().1 - g.bounds().0).length();
        for i in 0..8 {
            let all = mesh.receiver_ids();
            let before: std::collections::HashMap<(u32, u32), Decisions> = all.iter().copied().zip(receivers_shadow_edges(&mesh, &g, &all, None, &ProgressSteps::new(&NoProgress))).map(|(r, e)| (r, e.decisions)).collect();
            let o = 1 + i % (objects - 1);
            let d = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5) * (0.05 * size);
            let new = g.moved(o, |p| p + d);
            let mut changed = Vec::new();
            mesh.move_object_listing(&g, &new, &mut grid, o, &mut changed);
            let moved = Moved { old: &g, object: o, boxes: [g.object_bounds(o), new.object_bounds(o)] };
            let own = g.object_tris(o);
            let old = |(l, t): (u32, u32)| before.get(&(l, t)).filter(|_| !own.contains(&t));
            let with = receivers_shadow_edges(&mesh, &new, &changed, Some((&moved, &old as &OldDecisions<'_>)), &ProgressSteps::new(&NoProgress));
            let fresh = receivers_shadow_edges(&mesh, &new, &changed, None, &ProgressSteps::new(&NoProgress));
            for ((r, a), b) in changed.iter().zip(&with).zip(&fresh) {
                assert_eq!((a.counts, &a.edges), (b.counts, &b.edges), "receiver {r:?} after moving object {o} by {d}");
                kept += a.kept;
                made += a.decisions.len();
            }
            g = new;
        }
    }
    assert!(kept > 0 && kept < made, "{kept} of {made} decisions kept");
}
