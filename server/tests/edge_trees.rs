//! Edge trees against the brute-force finder on the shared real meshes (paper 000 §6.4):
//! silhouettes, forward-facing sharp edges and boundary edges identical to testing every
//! edge, from 1,000 random viewpoints each on the bunny, the dragon and the torus; shadow
//! events (point lights; VE and EV events of polygonal lights) identical to testing every
//! edge and vertex. The dragon is loaded once for the whole test binary.
use edgepoint_scene::{light::polygon_normal, Mesh, NoProgress};
use edgepoint_server::edges::brute;
use edgepoint_server::edges::events::{find_events, find_events_brute, LocalLight, VertexRings};
use edgepoint_server::edges::geometric::{MeshEdgeTrees, SharpTree};
use glam::Vec3;
use edgepoint_server::edges::sample::viewpoints;
use edgepoint_server::rng::Rng;
use rayon::prelude::*;
use std::sync::{Arc, OnceLock};

fn data(path: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data").join(path)
}

/// The model of a data file (its largest object), with its trees.
fn model(path: &str) -> (Arc<Mesh>, MeshEdgeTrees) {
    let scene = edgepoint_scene::load::load_path(&data(path), &NoProgress)
        .unwrap_or_else(|e| panic!("{path}: {e} (the shared data is expected at CARGO_MANIFEST_DIR/../../shared/data)"));
    let mesh = scene.objects.iter().max_by_key(|o| o.mesh.edges.len()).unwrap().mesh.clone();
    let trees = MeshEdgeTrees::build(&mesh, &NoProgress);
    (mesh, trees)
}

fn dragon() -> &'static (Arc<Mesh>, MeshEdgeTrees) {
    static D: OnceLock<(Arc<Mesh>, MeshEdgeTrees)> = OnceLock::new();
    D.get_or_init(|| model("dragon/dragon_vrip.ply"))
}

/// Random eyes: uniform directions at 0.3 to 4 bounding radii from the centre (some inside
/// the bounding sphere, most outside).
fn eyes(mesh: &Mesh, n: usize, seed: u64) -> Vec<Vec3> {
    viewpoints(mesh.bounds, n, seed, 0.3, 4.0)
}

/// Geometric edges from the trees equal brute force (all three kinds, exact sets).
fn geometric_equal(mesh: &Mesh, trees: &MeshEdgeTrees, views: usize, seed: u64) {
    let eyes = eyes(mesh, views, seed);
    let mut silhouettes = 0usize;
    let mut sharp = SharpTree::default();
    for (k, cutoff) in [85.0f32, 40.0].into_iter().enumerate() {
        let cos = cutoff.to_radians().cos();
        trees.prepare_sharp(mesh, cos, &mut sharp);
        let part = &eyes[k * views / 2..(k + 1) * views / 2];
        let sharp = &sharp;
        silhouettes += part
            .par_iter()
            .map(|&eye| {
                let mut want = Vec::new();
                brute::mesh_edges(mesh, eye, cos, &mut want);
                let mut got = Vec::new();
                trees.query(sharp, eye, &mut got, &mut Vec::new());
                want.sort_unstable();
                got.sort_unstable();
                assert!(got == want, "eye {eye}, cut-off {cutoff}: tree {} edges, brute force {}", got.len(), want.len());
                got.iter().filter(|e| e.1 == edgepoint_server::edges::EdgeKind::Silhouette).count()
            })
            .sum::<usize>();
    }
    assert!(silhouettes > views, "the views see silhouettes");
}

#[test]
fn bunny_geometric_edges_equal_brute_force_from_1000_views() {
    let (mesh, trees) = model("bunny/bun_zipper.ply");
    assert!(!trees.boundary.is_empty(), "the bunny has holes: boundary edges are exercised");
    geometric_equal(&mesh, &trees, 1000, 1);
}

#[test]
fn torus_geometric_edges_equal_brute_force_from_1000_views() {
    let (mesh, trees) = model("torus/torus.obj");
    geometric_equal(&mesh, &trees, 1000, 2);
}

#[test]
fn dragon_geometric_edges_equal_brute_force_from_1000_views() {
    let (mesh, trees) = dragon();
    assert_eq!(trees.silhouette.len + trees.boundary.len(), mesh.edges.len(), "every dragon edge is in a tree");
    geometric_equal(mesh, trees, 1000, 3);
}

/// A random convex polygonal light near the mesh facing its centre: 3 to 6 vertices on a
/// (slightly squashed) circle of radius 0.05 to 1 bounding radius.
fn area_light(mesh: &Mesh, g: &mut Rng) -> LocalLight {
    let (lo, hi) = mesh.bounds;
    let (c, r) = ((lo + hi) * 0.5, (hi - lo).length() * 0.5);
    let at = c + g.direction() * r * (1.2 + 2.0 * g.unit());
    let n = (c - at).normalize();
    let (u, v) = n.any_orthonormal_pair();
    let k = 3 + g.below(4);
    let size = r * (0.05 + 0.95 * g.unit());
    let squash = 0.4 + 0.6 * g.unit();
    let phase = g.unit() * 6.0;
    let mut vertices: Vec<Vec3> = (0..k)
        .map(|i| {
            let a = phase + i as f32 * std::f32::consts::TAU / k as f32;
            at + (u * a.cos() + v * a.sin() * squash) * size
        })
        .collect();
    if polygon_normal(&vertices).dot(n) < 0.0 {
        vertices.reverse();
    }
    let normal = polygon_normal(&vertices).normalize();
    let centroid = vertices.iter().copied().sum::<Vec3>() / k as f32;
    LocalLight::Polygon { vertices, normal, centroid }
}

fn events_equal(mesh: &Mesh, trees: &MeshEdgeTrees, points: usize, areas: usize, seed: u64) {
    let rings = VertexRings::build(mesh);
    let mut g = Rng::new(seed);
    let (lo, hi) = mesh.bounds;
    let (c, r) = ((lo + hi) * 0.5, (hi - lo).length() * 0.5);
    let mut lights: Vec<LocalLight> = (0..points).map(|_| LocalLight::Point(c + g.direction() * r * (0.5 + 3.0 * g.unit()))).collect();
    lights.extend((0..areas).map(|_| area_light(mesh, &mut g)));
    let (mut ve, mut ev) = (0usize, 0usize);
    for l in &lights {
        let got = find_events(mesh, trees, Some(&rings), l);
        let want = find_events_brute(mesh, Some(&rings), l);
        assert!(got == want, "light {l:?}: tree {} events, brute force {}", got.len(), want.len());
        for e in &got {
            match e.generator {
                edgepoint_server::edges::events::Generator::VE { .. } => ve += 1,
                edgepoint_server::edges::events::Generator::EV { .. } => ev += 1,
                _ => {}
            }
        }
    }
    assert!(areas == 0 || (ve > 0 && ev > 0), "VE {ve} EV {ev}");
}

#[test]
fn bunny_shadow_events_equal_brute_force() {
    let (mesh, trees) = model("bunny/bun_zipper.ply");
    events_equal(&mesh, &trees, 40, 40, 11);
}

#[test]
fn torus_shadow_events_equal_brute_force() {
    let (mesh, trees) = model("torus/torus.obj");
    events_equal(&mesh, &trees, 40, 60, 12);
}

#[test]
fn dragon_shadow_events_equal_brute_force() {
    let (mesh, trees) = dragon();
    events_equal(mesh, trees, 10, 10, 13);
}
