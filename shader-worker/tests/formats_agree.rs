//! Issue 13 item 7: scene files written here in each format, loaded through
//! `edgepoint_scene::load::load_files` and shaded by the worker's `direct` shader.
//! - A diffuse plane under a polygonal area light (Mitsuba `rectangle` emitter, OBJ `Ke`
//!   pentagon) against Lambert's closed form for the polygon's irradiance.
//! - One small box scene written as OBJ + MTL, glTF (+ .bin) and Mitsuba XML: cameras,
//!   lights and world-space triangles agree after each format's transforms, and the images
//!   rendered with identical seeds agree pixel by pixel.
mod common_scenes;
use common_scenes::polygon_irradiance;
use edgepoint_scene::load::{load_files, NamedBytes};
use edgepoint_scene::{Bsdf, Camera, Light, NoProgress, Scene};
use edgepoint_worker::{shade_batch, LoadedScene, RayRequest, ShaderSpec};
use glam::{Affine3A, Mat3, Quat, Vec3};
use std::collections::HashMap;
use std::f32::consts::PI;

fn nb(name: &str, data: &[u8]) -> NamedBytes {
    NamedBytes { name: name.into(), data: data.to_vec() }
}

fn load(files: &[NamedBytes]) -> Scene {
    let s = load_files(files, &NoProgress).unwrap_or_else(|e| panic!("{}: {e}", files[0].name));
    s.validate().unwrap();
    s
}

fn close(a: Vec3, b: Vec3, tol: f32) -> bool {
    (a - b).abs().max_element() <= tol
}

fn direct(shadow_rays: u32) -> ShaderSpec {
    let p = HashMap::from([("shadow_rays".to_string(), shadow_rays as f64), ("ambient".to_string(), 0.0)]);
    ShaderSpec::parse("direct", &p).unwrap()
}

/// `poly` and `want` are the same polygon: equal up to a cyclic shift (same winding).
fn same_polygon(poly: &[Vec3], want: &[Vec3], tol: f32) -> bool {
    poly.len() == want.len() && (0..want.len()).any(|s| (0..want.len()).all(|i| close(poly[(i + s) % poly.len()], want[i], tol)))
}

// ---------------------------------------------------------------- closed form

/// Shades the floor point `p` (seen from above, off to the side of the light) `seeds`
/// times with `shadow_rays` light samples each; returns the red channels.
fn shade_floor_point(loaded: &LoadedScene, p: Vec3, seeds: u64, shadow_rays: u32) -> Vec<f32> {
    let inst = loaded.instances(&loaded.default_transforms());
    let origin = p + Vec3::new(2.5, 2.0, 2.5);
    let r = RayRequest { id: 3, pixel: [0, 0], origin, direction: p - origin };
    (0..seeds)
        .map(|seed| {
            let out = shade_batch(loaded, &inst, &direct(shadow_rays), seed, &[r]);
            let h = out.samples[0].hit.expect("the floor is hit");
            assert!((h.position - p).length() < 1e-4, "the ray reaches the floor point {p}, not {}", h.position);
            out.samples[0].rgb.x
        })
        .collect()
}

/// The floor under the light at several points against ρ/π · L · E(polygon): the mean of
/// `SEEDS` independent estimates must lie within 5 standard errors (measured from the
/// estimates themselves) plus a float-summation floor of 1e-4 relative; the estimates must
/// themselves be tight (relative spread under 1 %), so the check is sharp. First the scene's
/// one light must be `light` (up to the starting corner), of `radiance`, facing down.
fn check_lambert(what: &str, s: Scene, light: &[Vec3], radiance: f32, albedo: f32) {
    const SEEDS: u64 = 16;
    assert_eq!(s.lights.len(), 1, "{what}");
    let Light::Area { vertices, radiance: r } = &s.lights[0] else { panic!("{what}: {:?}", s.lights[0]) };
    assert!(same_polygon(vertices, light, 1e-5), "{what}: {vertices:?} vs {light:?}");
    assert_eq!(*r, Vec3::splat(radiance), "{what}");
    assert!(s.lights[0].normal().unwrap().y < -0.8, "{what}: the light faces down");
    let loaded = LoadedScene::build(s, "t".into(), &NoProgress);
    let mut worst = 0f32;
    for p in FLOOR_POINTS {
        let est = shade_floor_point(&loaded, p, SEEDS, 1024);
        let n = est.len() as f32;
        let mean = est.iter().sum::<f32>() / n;
        let sd = (est.iter().map(|e| (e - mean).powi(2)).sum::<f32>() / (n - 1.0)).sqrt();
        let expect = albedo / PI * radiance * polygon_irradiance(p, Vec3::Y, light);
        assert!(expect > 1e-3, "the point {p} sees the light");
        assert!(sd / expect < 0.01, "at {p}: estimates spread {sd} around {mean}");
        let tol = 5.0 * sd / n.sqrt() + 1e-4 * expect;
        let rel = (mean - expect).abs() / expect;
        eprintln!("{what} at {p}: shaded {mean:.6} (sd {sd:.2e}) closed form {expect:.6}, relative error {rel:.2e}");
        assert!((mean - expect).abs() <= tol, "at {p}: shaded {mean} vs Lambert {expect} (tolerance {tol})");
        worst = worst.max(rel);
    }
    eprintln!("{what}: worst relative error {worst:.2e}");
}

const FLOOR_POINTS: [Vec3; 5] =
    [Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.9, 0.0, -0.3), Vec3::new(-0.6, 0.0, 0.5), Vec3::new(0.3, 0.0, 0.8), Vec3::new(1.5, 0.0, 1.2)];

#[test]
fn mitsuba_rectangle_light_over_a_diffuse_plane_matches_lambert() {
    // The lamp: a 0.8 × 0.5 rectangle turned to face down (+90° about x), tilted 25° more
    // about x, turned 15° about y, at height 1.
    let xml = r#"<scene version="3.0.0">
    <shape type="rectangle" id="floor">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf>
    </shape>
    <shape type="rectangle" id="lamp">
        <transform name="to_world">
            <scale x="0.4" y="0.25"/>
            <rotate x="1" angle="115"/>
            <rotate y="1" angle="15"/>
            <translate y="1"/>
        </transform>
        <emitter type="area"><rgb name="radiance" value="4, 4, 4"/></emitter>
    </shape>
</scene>"#;
    let s = load(&[nb("lambert.xml", xml.as_bytes())]);
    // The polygon computed here from the transform as written (Mitsuba applies the listed
    // operations first to last; its rectangle spans [-1, 1]² facing +z).
    let m = Affine3A::from_translation(Vec3::Y)
        * Affine3A::from_rotation_y(15f32.to_radians())
        * Affine3A::from_rotation_x(115f32.to_radians())
        * Affine3A::from_scale(Vec3::new(0.4, 0.25, 1.0));
    let poly: Vec<Vec3> = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(x, y)| m.transform_point3(Vec3::new(x, y, 0.0))).to_vec();
    check_lambert("mitsuba rectangle", s, &poly, 4.0, 0.5);
}

#[test]
fn obj_pentagon_light_over_a_diffuse_plane_matches_lambert() {
    // A regular pentagon of radius 0.5 at height 0.9, wound from +x towards +z (x × z = -y) so it
    // faces down, tilted by lifting one side; the floor one 6 × 6 quad.
    let poly: Vec<Vec3> = (0..5)
        .map(|i| {
            let a = i as f32 * std::f32::consts::TAU / 5.0;
            let (x, z) = (0.5 * a.cos() + 0.1, 0.5 * a.sin() - 0.2);
            Vec3::new(x, 0.9 + 0.3 * x, z)
        })
        .collect();
    let mut obj = String::from("mtllib m.mtl\no floor\nv -3 0 -3\nv -3 0 3\nv 3 0 3\nv 3 0 -3\nusemtl grey\nf 1 2 3 4\no lamp\n");
    for v in &poly {
        obj += &format!("v {} {} {}\n", v.x, v.y, v.z);
    }
    obj += "usemtl glow\nf 5 6 7 8 9\n";
    let mtl = "newmtl grey\nKd 0.6 0.6 0.6\nnewmtl glow\nKd 0 0 0\nKe 3 3 3\n";
    let s = load(&[nb("lambert.obj", obj.as_bytes()), nb("m.mtl", mtl.as_bytes())]);
    check_lambert("obj pentagon", s, &poly, 3.0, 0.6);
}

// ---------------------------------------------------------------- one box, three formats

/// The scene, as the test means it: unit meshes (Mitsuba's `rectangle` [-1, 1]² facing +z,
/// `cube` [-1, 1]³) placed by these world transforms.
struct Part {
    name: &'static str,
    cube: bool,
    translate: Vec3,
    rotate: Quat,
    scale: Vec3,
}

impl Part {
    fn matrix(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(self.scale, self.rotate, self.translate)
    }
}

fn deg(a: f32) -> f32 {
    a.to_radians()
}

fn parts() -> [Part; 4] {
    [
        Part { name: "floor", cube: false, translate: Vec3::ZERO, rotate: Quat::from_rotation_x(deg(-90.0)), scale: Vec3::splat(2.0) },
        Part { name: "wall", cube: false, translate: Vec3::new(0.0, 2.0, -2.0), rotate: Quat::IDENTITY, scale: Vec3::splat(2.0) },
        Part {
            name: "box",
            cube: true,
            translate: Vec3::new(0.4, 0.5, -0.2),
            rotate: Quat::from_rotation_y(deg(30.0)),
            scale: Vec3::new(0.3, 0.5, 0.4),
        },
        Part {
            name: "lamp",
            cube: false,
            translate: Vec3::new(0.8, 2.2, 1.0),
            rotate: Quat::from_rotation_y(deg(20.0)) * Quat::from_rotation_x(deg(90.0)),
            scale: Vec3::new(0.5, 0.3, 1.0),
        },
    ]
}

const RADIANCE: Vec3 = Vec3::new(24.0, 18.0, 12.0);
const WHITE: f32 = 0.7;
const RED: [f32; 3] = [0.7, 0.15, 0.1];
/// Below the lamp's height, so the camera sees its emitting side.
const EYE: Vec3 = Vec3::new(2.5, 1.4, 3.5);
const TARGET: Vec3 = Vec3::new(0.1, 1.2, -0.3);
/// Tilted: the camera rolls a little.
const UP: Vec3 = Vec3::new(0.15, 1.0, 0.0);
const W: u32 = 40;
const H: u32 = 32;
/// Mitsuba's `fov` on the x axis of the 40 × 32 film.
const FOV_X: f32 = 50.0;

fn fov_y_degrees() -> f32 {
    2.0 * ((FOV_X.to_radians() / 2.0).tan() * H as f32 / W as f32).atan().to_degrees()
}

/// The camera as edgepoint means it (looks at TARGET; `up` is orthonormalised by the frame).
fn camera() -> Camera {
    Camera { eye: EYE, target: TARGET, up: UP, fov_y_degrees: fov_y_degrees() }
}

/// Corners of the unit quad (facing +z, counter-clockwise seen from the front).
const QUAD: [[f32; 2]; 4] = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]];

/// The unit cube's six faces, each four corners counter-clockwise seen from outside, with
/// its outward normal.
fn cube_faces() -> Vec<([Vec3; 4], Vec3)> {
    let mut out = Vec::new();
    for axis in 0..3 {
        for sign in [1.0f32, -1.0] {
            let n = Vec3::AXES[axis] * sign;
            // u × v = n: (y, z) for x, (z, x) for y, (x, y) for z; swapped for -n.
            let (mut u, mut v) = (Vec3::AXES[(axis + 1) % 3], Vec3::AXES[(axis + 2) % 3]);
            if sign < 0.0 {
                std::mem::swap(&mut u, &mut v);
            }
            out.push((QUAD.map(|[a, b]| n + a * u + b * v), n));
        }
    }
    out
}

/// Each part's faces in its local space.
fn local_faces(p: &Part) -> Vec<([Vec3; 4], Vec3)> {
    if p.cube {
        cube_faces()
    } else {
        vec![(QUAD.map(|[a, b]| Vec3::new(a, b, 0.0)), Vec3::Z)]
    }
}

fn expected_light() -> Vec<Vec3> {
    let lamp = &parts()[3];
    QUAD.map(|[a, b]| lamp.matrix().transform_point3(Vec3::new(a, b, 0.0))).to_vec()
}

// ----- Mitsuba XML

/// The scene in Mitsuba 3 XML. `white` and `red` are the two BSDFs' XML (the glTF
/// comparison needs plastic, the OBJ one diffuse). Transforms as `scale`, `rotate` (the
/// quaternions' axis-angle), `translate` — applied in that order, as the parts mean them.
fn mitsuba_xml(white: &str, red: &str) -> String {
    let mut x = String::from(r#"<scene version="3.0.0">"#);
    x += &format!(
        r#"
    <sensor type="perspective">
        <float name="fov" value="{FOV_X}"/>
        <string name="fov_axis" value="x"/>
        <transform name="to_world">
            <lookat origin="{}, {}, {}" target="{}, {}, {}" up="{}, {}, {}"/>
        </transform>
        <film type="hdrfilm"><integer name="width" value="{W}"/><integer name="height" value="{H}"/></film>
    </sensor>
    <bsdf type="twosided" id="white">{white}</bsdf>
    <bsdf type="twosided" id="red">{red}</bsdf>"#,
        EYE.x, EYE.y, EYE.z, TARGET.x, TARGET.y, TARGET.z, UP.x, UP.y, UP.z
    );
    for p in parts() {
        let (axis, angle) = p.rotate.to_axis_angle();
        let ty = if p.cube { "cube" } else { "rectangle" };
        let material = match p.name {
            "box" => r#"<ref id="red"/>"#.to_string(),
            "lamp" => format!(r#"<ref id="white"/><emitter type="area"><rgb name="radiance" value="{}, {}, {}"/></emitter>"#, RADIANCE.x, RADIANCE.y, RADIANCE.z),
            _ => r#"<ref id="white"/>"#.to_string(),
        };
        x += &format!(
            r#"
    <shape type="{ty}" id="{}">
        <transform name="to_world">
            <scale x="{}" y="{}" z="{}"/>
            <rotate x="{}" y="{}" z="{}" angle="{}"/>
            <translate x="{}" y="{}" z="{}"/>
        </transform>
        {material}
    </shape>"#,
            p.name,
            p.scale.x,
            p.scale.y,
            p.scale.z,
            axis.x,
            axis.y,
            axis.z,
            angle.to_degrees(),
            p.translate.x,
            p.translate.y,
            p.translate.z
        );
    }
    x + "\n</scene>\n"
}

fn diffuse_xml(c: [f32; 3]) -> String {
    format!(r#"<bsdf type="diffuse"><rgb name="reflectance" value="{}, {}, {}"/></bsdf>"#, c[0], c[1], c[2])
}

/// Smooth plastic of index 1.5 — what a glTF dielectric of roughness 0 is.
fn plastic_xml(c: [f32; 3]) -> String {
    format!(
        r#"<bsdf type="plastic"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1.0"/><rgb name="diffuse_reflectance" value="{}, {}, {}"/></bsdf>"#,
        c[0], c[1], c[2]
    )
}

// ----- OBJ

/// The scene as OBJ + MTL. OBJ has no transforms and no camera: the world-space corners are
/// written out (computed with the parts' matrices) and the camera is given by hand.
fn obj_files() -> Vec<NamedBytes> {
    let mut obj = String::from("mtllib box.mtl\n");
    let mut next = 1;
    for p in parts() {
        obj += &format!("o {}\nusemtl {}\n", p.name, match p.name { "box" => "red", "lamp" => "glow", _ => "white" });
        for (corners, _) in local_faces(&p) {
            for c in corners {
                let w = p.matrix().transform_point3(c);
                obj += &format!("v {} {} {}\n", w.x, w.y, w.z);
            }
            obj += &format!("f {} {} {} {}\n", next, next + 1, next + 2, next + 3);
            next += 4;
        }
    }
    let mtl = format!(
        "newmtl white\nKd {WHITE} {WHITE} {WHITE}\nnewmtl red\nKd {} {} {}\nnewmtl glow\nKd {WHITE} {WHITE} {WHITE}\nKe {} {} {}\n",
        RED[0], RED[1], RED[2], RADIANCE.x, RADIANCE.y, RADIANCE.z
    );
    vec![nb("box.obj", obj.as_bytes()), nb("box.mtl", mtl.as_bytes())]
}

// ----- glTF

/// The scene as glTF 2.0 JSON with an external .bin: one quad and one cube mesh (with
/// normals), the box under a parent node that carries its translation (the hierarchy), the
/// lamp an emissive material (factor × KHR_materials_emissive_strength), the camera a node
/// looking down its -z. glTF cannot say "Lambertian": a dielectric of roughness 0 is smooth
/// plastic, so this file is compared with the plastic Mitsuba version.
fn gltf_files() -> Vec<NamedBytes> {
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut meshes = Vec::new();
    for (mi, faces) in [local_faces(&parts()[0]), cube_faces()].into_iter().enumerate() {
        let pos: Vec<Vec3> = faces.iter().flat_map(|(c, _)| *c).collect();
        let nrm: Vec<Vec3> = faces.iter().flat_map(|(_, n)| [*n; 4]).collect();
        let idx: Vec<u16> = (0..faces.len() as u16).flat_map(|f| [0, 1, 2, 0, 2, 3].map(|k| 4 * f + k)).collect();
        let (lo, hi) = pos.iter().fold((Vec3::MAX, Vec3::MIN), |(l, h), p| (l.min(*p), h.max(*p)));
        let base = accessors.len();
        for (data, count, ty, ct, minmax) in [
            (pos.iter().flat_map(|v| v.to_array()).flat_map(f32::to_le_bytes).collect::<Vec<u8>>(), pos.len(), "VEC3", 5126, true),
            (nrm.iter().flat_map(|v| v.to_array()).flat_map(f32::to_le_bytes).collect(), nrm.len(), "VEC3", 5126, false),
            (idx.iter().flat_map(|i| i.to_le_bytes()).collect(), idx.len(), "SCALAR", 5123, false),
        ] {
            while !bin.len().is_multiple_of(4) {
                bin.push(0);
            }
            views.push(format!(r#"{{"buffer": 0, "byteOffset": {}, "byteLength": {}}}"#, bin.len(), data.len()));
            bin.extend(data);
            let mm = if minmax { format!(r#", "min": [{}, {}, {}], "max": [{}, {}, {}]"#, lo.x, lo.y, lo.z, hi.x, hi.y, hi.z) } else { String::new() };
            accessors.push(format!(r#"{{"bufferView": {}, "componentType": {ct}, "count": {count}, "type": "{ty}"{mm}}}"#, views.len() - 1));
        }
        meshes.push((mi, base));
    }
    let prim = |mesh: usize, mat: usize| {
        let base = meshes[mesh].1;
        format!(r#"{{"primitives": [{{"attributes": {{"POSITION": {}, "NORMAL": {}}}, "indices": {}, "material": {mat}}}]}}"#, base, base + 1, base + 2)
    };
    // Meshes: 0 white quad, 1 red cube, 2 glowing quad.
    let mesh_json = [prim(0, 0), prim(1, 1), prim(0, 2)].join(", ");
    let q = |r: Quat| format!("[{}, {}, {}, {}]", r.x, r.y, r.z, r.w);
    let v = |a: Vec3| format!("[{}, {}, {}]", a.x, a.y, a.z);
    let [floor, wall, bx, lamp] = parts();
    let node = |p: &Part, mesh: usize| format!(r#"{{"name": "{}", "mesh": {mesh}, "translation": {}, "rotation": {}, "scale": {}}}"#, p.name, v(p.translate), q(p.rotate), v(p.scale));
    // The camera node: its local x right, y up, -z forward (glTF's convention).
    let f = (TARGET - EYE).normalize();
    let right = f.cross(UP).normalize();
    let cam_rot = Quat::from_mat3(&Mat3::from_cols(right, right.cross(f), -f));
    let box_child = format!(r#"{{"name": "box", "mesh": 1, "rotation": {}, "scale": {}}}"#, q(bx.rotate), v(bx.scale));
    let json = format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "extensionsUsed": ["KHR_materials_emissive_strength"],
  "scene": 0,
  "scenes": [{{"nodes": [0, 1, 2, 4, 5]}}],
  "nodes": [
    {},
    {},
    {{"name": "box parent", "translation": {}, "children": [3]}},
    {box_child},
    {},
    {{"name": "cam", "camera": 0, "translation": {}, "rotation": {}}}
  ],
  "cameras": [{{"type": "perspective", "perspective": {{"yfov": {}, "aspectRatio": {}, "znear": 0.01}}}}],
  "meshes": [{mesh_json}],
  "materials": [
    {{"name": "white", "doubleSided": true, "pbrMetallicRoughness": {{"baseColorFactor": [{WHITE}, {WHITE}, {WHITE}, 1], "metallicFactor": 0, "roughnessFactor": 0}}}},
    {{"name": "red", "doubleSided": true, "pbrMetallicRoughness": {{"baseColorFactor": [{}, {}, {}, 1], "metallicFactor": 0, "roughnessFactor": 0}}}},
    {{"name": "glow", "doubleSided": true, "pbrMetallicRoughness": {{"baseColorFactor": [{WHITE}, {WHITE}, {WHITE}, 1], "metallicFactor": 0, "roughnessFactor": 0}},
      "emissiveFactor": [1, 0.75, 0.5], "extensions": {{"KHR_materials_emissive_strength": {{"emissiveStrength": 24}}}}}}
  ],
  "buffers": [{{"uri": "box.bin", "byteLength": {}}}],
  "bufferViews": [{}],
  "accessors": [{}]
}}"#,
        node(&floor, 0),
        node(&wall, 0),
        v(bx.translate),
        node(&lamp, 2),
        v(EYE),
        q(cam_rot),
        fov_y_degrees().to_radians(),
        W as f32 / H as f32,
        RED[0],
        RED[1],
        RED[2],
        bin.len(),
        views.join(", "),
        accessors.join(", ")
    );
    vec![nb("box.gltf", json.as_bytes()), nb("box.bin", &bin)]
}

// ----- comparison

/// A scene's world-space triangles by object name.
fn world_triangles(s: &Scene) -> HashMap<String, Vec<[Vec3; 3]>> {
    s.objects
        .iter()
        .map(|o| {
            let t = o.mesh.triangles.iter().map(|t| t.map(|i| o.transform.transform_point3(o.mesh.positions[i as usize]))).collect();
            (o.name.clone(), t)
        })
        .collect()
}

fn distance_to_triangle(p: Vec3, t: &[Vec3; 3]) -> f32 {
    // Inside the prism over the triangle: the distance to its plane; else to the nearest edge.
    let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
    let inside = (0..3).all(|i| (t[(i + 1) % 3] - t[i]).cross(p - t[i]).dot(n) >= -1e-7);
    if inside {
        return (p - t[0]).dot(n).abs();
    }
    (0..3)
        .map(|i| {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            let h = ((p - a).dot(b - a) / (b - a).length_squared()).clamp(0.0, 1.0);
            (p - (a + h * (b - a))).length()
        })
        .fold(f32::MAX, f32::min)
}

/// `a` and `b` are the same oriented surface however each is triangulated: equal areas, and
/// points spread over every triangle of `a` lie on a triangle of `b` with the same normal.
/// Returns the largest distance found.
fn same_surface(what: &str, a: &[[Vec3; 3]], b: &[[Vec3; 3]]) -> f32 {
    let area = |ts: &[[Vec3; 3]]| ts.iter().map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()).sum::<f32>();
    let (aa, ab) = (area(a), area(b));
    assert!((aa - ab).abs() <= 1e-5 * aa.max(1.0), "{what}: areas {aa} vs {ab}");
    let mut worst = 0f32;
    for t in a {
        let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
        for w in [[1.0 / 3.0; 3], [0.6, 0.2, 0.2], [0.2, 0.6, 0.2], [0.2, 0.2, 0.6]] {
            let p = w[0] * t[0] + w[1] * t[1] + w[2] * t[2];
            let d = b
                .iter()
                .filter(|u| (u[1] - u[0]).cross(u[2] - u[0]).normalize().dot(n) > 1.0 - 1e-5)
                .map(|u| distance_to_triangle(p, u))
                .fold(f32::MAX, f32::min);
            assert!(d < 1e-5, "{what}: the point {p} (normal {n}) is on no triangle of the other file facing the same way (nearest {d})");
            worst = worst.max(d);
        }
    }
    worst
}

/// Compares a loaded scene with the scene as meant: objects' world-space surfaces (against
/// the reference scene `reference`), the light, the camera (unless the format has none).
fn check_scene(what: &str, s: &Scene, reference: &Scene, has_camera: bool) {
    if has_camera {
        let (got, want) = (s.camera.frame(W, H), camera().frame(W, H));
        for (k, g, w) in [("eye", got.eye, want.eye), ("forward", got.forward, want.forward), ("right", got.right, want.right), ("up", got.up, want.up)] {
            assert!(close(g, w, 1e-5), "{what}: camera {k} {g} vs {w}");
        }
        assert!((s.camera.fov_y_degrees - fov_y_degrees()).abs() < 1e-3, "{what}: fov {} vs {}", s.camera.fov_y_degrees, fov_y_degrees());
    }
    assert_eq!(s.ambient, Vec3::ZERO, "{what}: scene files light themselves");
    assert_eq!(s.lights.len(), 1, "{what}: {:?}", s.lights);
    let Light::Area { vertices, radiance } = &s.lights[0] else { panic!("{what}: {:?}", s.lights[0]) };
    assert!(same_polygon(vertices, &expected_light(), 1e-5), "{what}: light {vertices:?} vs {:?}", expected_light());
    assert_eq!(*radiance, RADIANCE, "{what}");
    let (mine, theirs) = (world_triangles(s), world_triangles(reference));
    let mut names: Vec<&String> = mine.keys().collect();
    names.sort();
    assert_eq!(names, ["box", "floor", "lamp", "wall"], "{what}: the objects");
    let mut worst = 0f32;
    for n in names {
        worst = worst.max(same_surface(&format!("{what} {n}"), &mine[n], &theirs[n]));
        worst = worst.max(same_surface(&format!("{what} {n} (reverse)"), &theirs[n], &mine[n]));
    }
    let red = &s.objects.iter().find(|o| o.name == "box").unwrap().material;
    assert_eq!(red.diffuse, Vec3::from(RED), "{what}");
    eprintln!("{what}: geometry agrees within {worst:.2e}");
}

fn render(s: Scene, cam: Camera) -> Vec<Vec3> {
    let frame = cam.frame(W, H);
    let loaded = LoadedScene::build(s, "x".into(), &NoProgress);
    let inst = loaded.instances(&loaded.default_transforms());
    let reqs: Vec<RayRequest> = (0..W * H)
        .map(|i| {
            let (o, d) = frame.ray((i % W) as f32 + 0.5, (i / W) as f32 + 0.5);
            RayRequest { id: i as u64, pixel: [i % W, i / W], origin: o, direction: d }
        })
        .collect();
    let out = shade_batch(&loaded, &inst, &direct(64), 11, &reqs);
    assert_eq!(out.nonfinite, 0);
    let mut img = vec![Vec3::ZERO; (W * H) as usize];
    for (r, s) in reqs.iter().zip(&out.samples) {
        img[(r.pixel[1] * W + r.pixel[0]) as usize] = s.rgb;
    }
    img
}

/// Pixel-by-pixel comparison: returns (largest difference, pixels differing by more than
/// 1e-3 relative to the pixel).
fn compare(what: &str, a: &[Vec3], b: &[Vec3]) -> (f32, usize) {
    let mut worst = 0f32;
    let mut off = 0;
    for (x, y) in a.iter().zip(b) {
        let d = (*x - *y).abs().max_element();
        worst = worst.max(d);
        if d > 1e-3 * x.max_element().max(0.05) {
            off += 1;
        }
    }
    eprintln!("{what}: max pixel difference {worst:.3e}, {off} of {} pixels differ by more than 1e-3 relative", a.len());
    (worst, off)
}

/// The image is a real picture of the scene: the lamp at its radiance, a red box, lit floor.
fn check_picture(what: &str, img: &[Vec3]) {
    assert!(img.iter().any(|p| close(*p, RADIANCE, 1e-3)), "{what}: the camera sees the lamp");
    assert!(img.iter().filter(|p| p.x > 0.02 && p.x > 3.0 * p.y).count() > 20, "{what}: the red box is in view");
    assert!(img.iter().filter(|p| p.min_element() > 0.02).count() > (W * H / 3) as usize, "{what}: mostly lit");
}

#[test]
fn one_box_scene_in_obj_gltf_and_mitsuba_agrees() {
    let white = [WHITE; 3];
    let xml_diffuse = mitsuba_xml(&diffuse_xml(white), &diffuse_xml(RED));
    let xml_plastic = mitsuba_xml(&plastic_xml(white), &plastic_xml(RED));
    let mts = load(&[nb("box.xml", xml_diffuse.as_bytes())]);
    let mts_plastic = load(&[nb("box.xml", xml_plastic.as_bytes())]);
    let obj = load(&obj_files());
    let gltf = load(&gltf_files());
    // The reference for geometry: the world-space faces written straight from the parts
    // (the OBJ); Mitsuba and glTF reach them through their transforms.
    check_scene("mitsuba", &mts, &obj, true);
    check_scene("gltf", &gltf, &obj, true);
    check_scene("obj", &obj, &mts, false);
    let mat = |s: &Scene, n: &str| s.objects.iter().find(|o| o.name == n).unwrap().material.bsdf.clone();
    assert_eq!(mat(&mts, "floor"), Bsdf::Diffuse);
    assert_eq!(mat(&obj, "floor"), Bsdf::Diffuse);
    assert_eq!(mat(&gltf, "floor"), Bsdf::Plastic { ior: 1.5, roughness: 0.0 });
    assert_eq!(mat(&mts_plastic, "floor"), mat(&gltf, "floor"));

    // Images, each with its file's camera (OBJ: the camera by hand), the same seed.
    let (mts_cam, gltf_cam) = (mts.camera, gltf.camera);
    let img_mts = render(mts, mts_cam);
    let img_obj = render(obj, camera());
    let img_mts_plastic = render(mts_plastic, mts_cam);
    let img_gltf = render(gltf, gltf_cam);
    for (n, i) in [("mitsuba", &img_mts), ("obj", &img_obj), ("mitsuba plastic", &img_mts_plastic), ("gltf", &img_gltf)] {
        check_picture(n, i);
    }
    let (d1, off1) = compare("obj vs mitsuba (diffuse)", &img_obj, &img_mts);
    let (d2, off2) = compare("gltf vs mitsuba (plastic)", &img_gltf, &img_mts_plastic);
    // The loaders give the same world-space triangles to float rounding (~1e-7), so the
    // same rays and seeds shade the same points: the images agree to float rounding, far
    // below the shading noise (64 shadow rays: ~1 % per pixel), with pixels up to 24.
    assert!(d1 < 1e-4 && off1 == 0, "obj and mitsuba images differ");
    assert!(d2 < 1e-4 && off2 == 0, "gltf and mitsuba images differ");
}
