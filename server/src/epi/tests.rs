//! The EPI on real scenes: occlusion culling against ray-cast visibility, pixel classes,
//! stage timing.
use super::*;
use crate::edges::brute::scene_edges;
use edgepoint_scene::{NoProgress, Scene};
use edgepoint_worker::LoadedScene;
use glam::Affine3A;

/// A point image of one ray through every pixel (jittered when `jitter`), with view depths
/// from ray casting; colours are irrelevant here.
fn ray_cast_points(loaded: &LoadedScene, cam: &CameraFrame, density: f64, seed: u64) -> PointImage {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let inst = loaded.instances(&loaded.default_transforms());
    let mut rng = testutil::Rng(seed);
    let mut pi = PointImage { width: w as u32, height: h as u32, ..Default::default() };
    for y in 0..h {
        for x in 0..w {
            let (u, v) = (rng.unit(), rng.unit());
            let has = rng.chance(density);
            let (o, d) = cam.ray(x as f32 + u, y as f32 + v);
            let depth = match inst.closest_hit(&loaded.bvh, o, d, 0.0, f32::INFINITY) {
                Some(hit) => (hit.position - cam.eye).dot(cam.forward),
                None => f32::INFINITY,
            };
            pi.point.push(if has { (y * w + x) as u32 } else { NO_POINT });
            pi.depth.push(if has { depth } else { f32::INFINITY });
            pi.subpixel.push([u, v]);
            pi.color.push(Vec3::ZERO);
            pi.age.push(if has { 0.0 } else { f32::INFINITY });
        }
    }
    pi
}

fn bunny() -> Option<Scene> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/bunny/bun_zipper.ply");
    if !path.exists() {
        eprintln!("skipping the bunny: {} not found", path.display());
        return None;
    }
    Some(edgepoint_scene::load::load_path(&path, &NoProgress).expect("bunny loads"))
}

/// Relative distance in front of an edge point by which a surface clearly hides it.
const HIDDEN_MARGIN: f32 = 0.1;

/// Points along every edge (projected on screen): (visible by ray casting, culled by the
/// conservative depth).
fn culling_against_visibility(scene: Scene, size: u32, density: f64) -> (usize, usize, usize, usize) {
    let cam = scene.camera.frame(size, size);
    let transforms: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
    let mut edges = Vec::new();
    scene_edges(&scene, &transforms, cam.eye, 85.0, &mut edges);
    let loaded = LoadedScene::build(scene, "test".into(), &NoProgress);
    let inst = loaded.instances(&transforms);
    let points = ray_cast_points(&loaded, &cam, density, 1);
    let mut depth = depth::ConservativeDepth::new(size as usize, size as usize);
    depth.compute(&points);
    let (mut visible, mut visible_culled, mut hidden, mut hidden_culled) = (0, 0, 0, 0);
    for e in &edges {
        for k in 0..16 {
            let p = e.a + (e.b - e.a) * ((k as f32 + 0.5) / 16.0);
            let Some((sx, sy, z)) = cam.project(p) else { continue };
            if !(sx >= 0.0 && sy >= 0.0 && sx < size as f32 && sy < size as f32) {
                continue;
            }
            let to = p - cam.eye;
            let dist = to.length();
            // Visible: nothing in front of the point (its own faces meet the ray only at it).
            // Hidden: a surface clearly in front (points hidden by less, where the ray grazes
            // the faces next to a silhouette, count as neither).
            let hit = inst.closest_hit(&loaded.bvh, cam.eye, to / dist, 0.0, dist * (1.0 - 2e-3));
            let culled = z > depth.at(sx.round() as i64, sy.round() as i64);
            match hit {
                None => {
                    visible += 1;
                    visible_culled += usize::from(culled);
                }
                Some(h) if h.t < dist * (1.0 - HIDDEN_MARGIN) => {
                    hidden += 1;
                    hidden_culled += usize::from(culled);
                }
                Some(_) => {}
            }
        }
    }
    (visible, visible_culled, hidden, hidden_culled)
}

#[test]
fn occlusion_culling_keeps_visible_edges_and_drops_most_hidden_ones() {
    let mut scenes = vec![("cornell-point", edgepoint_scene::builtin::load("cornell-point").unwrap())];
    scenes.extend(bunny().map(|b| ("bunny", b)));
    for (name, scene) in scenes {
        for density in [1.0, 0.2, 0.05] {
            let (v, vc, hdn, hc) = culling_against_visibility(scene.clone(), 160, density);
            eprintln!("{name} at density {density}: {vc} of {v} visible edge points culled, {hc} of {hdn} hidden ones");
            assert!(v > 200 && hdn > 20, "{name}: {v} visible, {hdn} hidden points");
            assert!((vc as f64) < 0.01 * v as f64, "{name} density {density}: {vc} of {v} visible edge points culled");
            let min_hidden = if density == 1.0 { 0.5 } else { 0.3 };
            assert!(hc as f64 > min_hidden * hdn as f64, "{name} density {density}: only {hc} of {hdn} hidden edge points culled");
        }
    }
}

#[test]
fn a_cornell_frame_has_mostly_empty_pixels_and_times_every_stage() {
    let scene = edgepoint_scene::builtin::load("cornell").unwrap();
    let size = 128;
    let cam = scene.camera.frame(size, size);
    let transforms: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
    let mut edges = Vec::new();
    scene_edges(&scene, &transforms, cam.eye, 85.0, &mut edges);
    let loaded = LoadedScene::build(scene, "test".into(), &NoProgress);
    let points = ray_cast_points(&loaded, &cam, 0.5, 2);
    let mut epi = Epi::new(size, size);
    let mut times = StageTimes::new();
    let c = epi.build(&edges, &cam, &points, true, &mut times);
    let n = size * size;
    assert_eq!(c.empty + c.simple + c.complex, n);
    assert!(c.empty > n * 8 / 10 && c.simple > n / 100 && c.complex < c.simple, "{c:?}");
    assert_eq!(c.edges.iter().sum::<u32>(), edges.len() as u32);
    assert!(c.raster.fragments > 0 && c.raster.culled > 0, "{c:?}");
    let (mut image, mut weights) = (vec![Vec3::ZERO; n as usize], vec![0.0; n as usize]);
    let r = epi.reconstruct(&points, Vec3::ZERO, &InterpOptions::default(), true, &mut image, &mut weights, &mut times);
    assert!(r.antialiased > 0 && r.complex_refined > 0, "{r:?}");
    let names: Vec<&str> = times.stages.iter().map(|s| s.0).collect();
    assert_eq!(names, [STAGE_RASTERIZE, STAGE_REACH, STAGE_INTERPOLATE, STAGE_SPREAD, STAGE_ANTIALIAS, STAGE_COMPLEX]);
    // Image-sized structures stay within the target of 16 bytes per pixel (the paper's
    // 15–17, §7.4), content-sized ones within 3 for this small frame's edges (24 bytes per
    // simple pixel, 1.7 % of the pixels, and the projected edges).
    let bytes = |m: Vec<(&str, usize)>| m.iter().map(|m| m.1).sum::<usize>() as f64 / n as f64;
    let (image_sized, content_sized) = (bytes(epi.memory()), bytes(epi.memory_content()));
    assert!(image_sized < 16.0 && content_sized < 3.0, "{image_sized} + {content_sized} B/px: {:?} {:?}", epi.memory(), epi.memory_content());
}

/// Classification pixel by pixel, straight from the definitions (§4.1–4.4): the oracle of
/// [`Epi::classify`], whose words without crossings take a shortcut and whose rows are
/// compiled for the CPU's vector width.
#[test]
fn classification_equals_the_per_pixel_definition_on_every_isa() {
    use super::testutil::{random_epi, random_points, Rng};
    let t = tables();
    let mut rng = Rng(41);
    for (w, h, density, long, short) in [(1, 1, 1.0, 1, 0), (70, 9, 0.8, 3, 4), (130, 40, 0.3, 6, 12), (64, 64, 1.0, 0, 0), (200, 17, 0.05, 9, 30)] {
        let points = random_points(w, h, density, &mut rng);
        let mut epi = random_epi(&points, long, short, true, &mut rng);
        for isa in interpolate::Isa::ALL.into_iter().filter(|i| i.available()) {
            let counts = epi.classify_isa(&points, isa);
            let mut want = EpiCounts::default();
            for y in 0..h {
                for x in 0..w {
                    let i = y * w + x;
                    let has = points.point[i] != NO_POINT;
                    let [u, v] = points.subpixel[i];
                    let r = if has { code::PIXEL.region_of(u, v) } else { 0 };
                    let m = epi.boundaries().mask(x, y);
                    let (p, simple, complex) = if m == 0 {
                        want.empty += 1;
                        want.usable_samples += has as u32;
                        (EpiPixel::new(code::EMPTY, r, has, false), false, false)
                    } else {
                        let c = code::PIXEL.classify(m);
                        let side = if has { t.pixel.side(c, r) } else { AMBIGUOUS };
                        let usable = has && side != AMBIGUOUS;
                        let primary_b = if usable { side == SIDE_B } else { t.pixel.area_a(c) < 0.5 };
                        let p = EpiPixel::new(c, r, usable, primary_b);
                        if p.is_simple() {
                            want.simple += 1;
                            want.usable_samples += usable as u32;
                            want.ambiguous_samples += (has && !usable) as u32;
                        } else {
                            want.complex += 1;
                        }
                        (p, p.is_simple(), !p.is_simple())
                    };
                    let at = format!("{isa:?}: pixel ({x},{y}) of {w}x{h}");
                    assert_eq!(epi.pixels()[i], p, "{at}");
                    let f = epi.flags();
                    assert_eq!(f.get(x, y, Flags::HAS), has, "{at}");
                    assert_eq!(f.get(x, y, Flags::USABLE), p.usable(), "{at}");
                    assert_eq!((f.get(x, y, Flags::SIMPLE), f.get(x, y, Flags::COMPLEX)), (simple, complex), "{at}");
                }
            }
            assert_eq!(counts, want, "{isa:?}: {w}x{h}");
        }
    }
}
