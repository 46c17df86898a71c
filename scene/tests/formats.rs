//! The scene formats of issue 13: Mitsuba 3 XML (the shared `cbox.xml` and hand-written
//! scenes), glTF 2.0 (`.gltf` with data-URI and external buffers, `.glb`), OBJ normals and
//! UVs, gzip, the gathering of referenced files and the errors that name file and place.
use base64::Engine;
use edgepoint_scene::load::{self, file_view, gather, load_files, load_path, spectrum, NamedBytes};
use edgepoint_scene::{Bsdf, Light, NoProgress, Scene, SceneError};
use glam::{Vec2, Vec3};
use std::io::Write;
mod common;
use common::data;

fn nb(name: &str, data: &[u8]) -> NamedBytes {
    NamedBytes { name: name.into(), data: data.to_vec() }
}

fn load(files: &[NamedBytes]) -> Result<Scene, SceneError> {
    load_files(files, &NoProgress)
}

fn close(a: Vec3, b: Vec3, tol: f32) -> bool {
    (a - b).abs().max_element() <= tol
}

fn gz(data: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(data).unwrap();
    e.finish().unwrap()
}

// ---------------------------------------------------------------- Mitsuba: the real box

#[test]
fn cbox_xml_loads_with_its_camera_film_materials_and_light() {
    let Some(p) = data("cornell_box/cbox.xml") else { return };
    let files = gather(&p).unwrap();
    let names: Vec<&str> = files.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names[0], "cbox.xml");
    assert_eq!(names.len(), 9, "the XML and its eight meshes: {names:?}");
    assert!(names.contains(&"meshes/cbox_luminaire.obj"));
    let s = load(&files).unwrap();
    s.validate().unwrap();
    // <lookat origin="278, 273, -800" target="278, 273, -799" up="0, 1, 0"/>, fov 39.3077
    // on the smaller axis of a square film: the vertical field of view.
    assert!(close(s.camera.eye, Vec3::new(278.0, 273.0, -800.0), 1e-3), "{:?}", s.camera);
    assert!(close((s.camera.target - s.camera.eye).normalize(), Vec3::Z, 1e-6));
    assert!(close(s.camera.up, Vec3::Y, 1e-6));
    assert!((s.camera.fov_y_degrees - 39.3077).abs() < 1e-4);
    let view = file_view(&files, None).unwrap();
    assert_eq!(view.film, Some((256, 256)), "width and height are `$res` = 256");
    assert_eq!(view.camera, Some(s.camera));
    // Eight shapes, nothing staged, no ambient.
    assert_eq!(s.objects.len(), 8);
    assert!(s.objects.iter().all(|o| o.name != "floor") && s.ambient == Vec3::ZERO);
    // One light: the luminaire quad, moved down 0.5 by its to_world, facing down.
    assert_eq!(s.lights.len(), 1);
    let Light::Area { vertices, radiance } = &s.lights[0] else { panic!("{:?}", s.lights[0]) };
    assert_eq!(vertices.len(), 4, "the quad's two triangles are one light");
    assert!(vertices.iter().all(|v| (v.y - 548.3).abs() < 1e-4), "{vertices:?}");
    assert!((s.lights[0].area() - 130.0 * 105.0).abs() < 1e-2);
    assert!(close(s.lights[0].normal().unwrap(), -Vec3::Y, 1e-6));
    // Its radiance: the spectrum 400:0, 500:8, 600:15.6, 700:18.4 as an emitter. The
    // expected value was computed independently (numpy: the same 1000-point CIE 1931 sum
    // over the 5 nm tables, no D65, Rec. 709 matrix).
    assert!(close(*radiance, Vec3::new(20.7108, 10.8546, 2.7712), 2e-3), "{radiance}");
    let lum = s.objects.iter().find(|o| o.name == "cbox_luminaire").unwrap();
    assert_eq!(lum.material.emission, *radiance, "the camera sees the light at its radiance");
    // Materials: one-sided diffuse (no twosided in the file), colours from the reflectance
    // spectra under D65.
    let mat = |n: &str| &s.objects.iter().find(|o| o.name == n).unwrap().material;
    for n in ["cbox_floor", "cbox_redwall", "cbox_greenwall", "cbox_smallbox"] {
        assert_eq!(mat(n).bsdf, Bsdf::Diffuse);
        assert!(!mat(n).two_sided, "{n}");
    }
    let (red, green, white) = (mat("cbox_redwall").diffuse, mat("cbox_greenwall").diffuse, mat("cbox_floor").diffuse);
    assert!(red.x > 0.4 && red.y < 0.1 && red.z < 0.1, "{red}");
    assert!(green.y > 0.25 && green.x < 0.15 && green.z < 0.15, "{green}");
    assert!(white.min_element() > 0.6 && white.max_element() < 0.8, "{white}");
    // The flat 0.78 reflectance of the light's BSDF is 0.78 grey (D65 is sRGB's white).
    assert!(close(lum.material.diffuse, Vec3::splat(0.78), 6e-3), "{}", lum.material.diffuse);
    // Its meshes carry their `vn` normals as corner attributes.
    let small = &s.objects.iter().find(|o| o.name == "cbox_smallbox").unwrap().mesh;
    assert_eq!(small.corners.normals.as_ref().unwrap().len(), small.triangles.len());
}

// ---------------------------------------------------------------- Mitsuba: hand-written

const XML: &str = r#"<scene version="3.0.0">
    <default name="w" value="320"/>
    <default name="metal" value="Au"/>
    <sensor type="perspective">
        <float name="fov" value="60"/>
        <string name="fov_axis" value="x"/>
        <transform name="to_world">
            <lookat origin="0, 1, 5" target="0, 1, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="$w"/>
            <integer name="height" value="240"/>
        </film>
    </sensor>
    <bsdf type="twosided" id="gold">
        <bsdf type="roughconductor">
            <string name="material" value="$metal"/>
            <float name="alpha" value="0.2"/>
        </bsdf>
    </bsdf>
    <bsdf type="dielectric" id="glass">
        <string name="int_ior" value="water"/>
        <float name="ext_ior" value="1.0"/>
    </bsdf>
    <bsdf type="roughplastic" id="plastic">
        <rgb name="diffuse_reflectance" value="0.1, 0.2, 0.3"/>
    </bsdf>
    <shape type="rectangle" id="floor">
        <transform name="to_world">
            <rotate x="1" angle="-90"/>
            <scale value="4"/>
        </transform>
        <ref id="plastic"/>
    </shape>
    <shape type="cube" id="box">
        <transform name="to_world">
            <scale x="0.5" y="1" z="0.5"/>
            <translate x="1" y="1" z="0"/>
        </transform>
        <ref id="gold"/>
    </shape>
    <shape type="sphere" id="ball">
        <point name="center" x="-1" y="0.5" z="0"/>
        <float name="radius" value="0.5"/>
        <ref id="glass"/>
    </shape>
    <shape type="rectangle" id="lamp">
        <transform name="to_world">
            <scale value="0.25"/>
            <rotate x="1" angle="90"/>
            <translate y="3"/>
        </transform>
        <emitter type="area">
            <rgb name="radiance" value="10, 9, 8"/>
        </emitter>
    </shape>
    <emitter type="point">
        <point name="position" x="2" y="3" z="1"/>
        <rgb name="intensity" value="5"/>
    </emitter>
    <emitter type="spot">
        <transform name="to_world"><lookat origin="0, 4, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
        <rgb name="intensity" value="7"/>
        <float name="cutoff_angle" value="30"/>
        <float name="beam_width" value="20"/>
    </emitter>
</scene>"#;

#[test]
fn hand_written_mitsuba_scene() {
    let files = [nb("s.xml", XML.as_bytes())];
    let s = load(&files).unwrap();
    s.validate().unwrap();
    // Camera: lookat, 60° horizontal on a 4:3 film → vertical 2 atan(tan 30° · 3/4).
    assert!(close(s.camera.eye, Vec3::new(0.0, 1.0, 5.0), 1e-6) && close(s.camera.target, Vec3::new(0.0, 1.0, 4.0), 1e-6));
    let want = (2.0 * (30f64.to_radians().tan() * 0.75).atan()).to_degrees() as f32;
    assert!((s.camera.fov_y_degrees - want).abs() < 1e-4, "{} vs {want}", s.camera.fov_y_degrees);
    assert_eq!(file_view(&files, None).unwrap().film, Some((320, 240)));
    let obj = |n: &str| s.objects.iter().find(|o| o.name == n).unwrap();
    // rotate -90° about x then scale 4: the [-1,1]² rectangle lies in y = 0, facing +y.
    let floor = obj("floor");
    let n = floor.transform.transform_vector3(floor.mesh.face_normals[0]).normalize();
    assert!(close(n, Vec3::Y, 1e-6), "{n}");
    let corner = floor.transform.transform_point3(Vec3::new(1.0, 1.0, 0.0));
    assert!(close(corner, Vec3::new(4.0, 0.0, -4.0), 1e-5), "{corner}");
    let Bsdf::Plastic { ior, roughness } = floor.material.bsdf else { panic!("{:?}", floor.material.bsdf) };
    assert!((ior - 1.49 / 1.000277).abs() < 1e-6 && roughness == 0.1, "{ior} {roughness}");
    assert_eq!(floor.material.diffuse, Vec3::new(0.1, 0.2, 0.3));
    // scale then translate: the cube spans [0.5, 1.5] × [0, 2] × [-0.5, 0.5].
    let bx = obj("box");
    let (lo, hi) = edgepoint_scene::geometry::transformed_box(&bx.transform, bx.mesh.bounds);
    assert!(close(lo, Vec3::new(0.5, 0.0, -0.5), 1e-5) && close(hi, Vec3::new(1.5, 2.0, 0.5), 1e-5), "{lo} {hi}");
    let Bsdf::Conductor { roughness, eta, .. } = bx.material.bsdf else { panic!("{:?}", bx.material.bsdf) };
    assert!((roughness - 0.2).abs() < 1e-6 && eta.z > eta.x, "gold: {eta}");
    assert!(bx.material.two_sided, "twosided wrapper");
    // The sphere: centre and radius, smooth normals pointing out of it.
    let ball = obj("ball");
    assert_eq!(ball.material.bsdf, Bsdf::Dielectric { ior: 1.333, roughness: 0.0 });
    let normals = ball.mesh.corners.normals.as_ref().unwrap();
    for (f, t) in ball.mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let p = ball.transform.transform_point3(ball.mesh.positions[t[k] as usize]);
            assert!(((p - Vec3::new(-1.0, 0.5, 0.0)).length() - 0.5).abs() < 1e-5);
            let n = ball.transform.transform_vector3(normals[f][k]).normalize();
            assert!(close(n, (p - Vec3::new(-1.0, 0.5, 0.0)).normalize(), 1e-4));
        }
    }
    // Lights: the lamp (scale, rotate +90° about x: facing -y, at y = 3), a point, a spot.
    assert_eq!(s.lights.len(), 3);
    let lamp = &s.lights[0];
    assert!(close(lamp.normal().unwrap(), -Vec3::Y, 1e-6) && (lamp.center().y - 3.0).abs() < 1e-6);
    assert!((lamp.area() - 0.25).abs() < 1e-5);
    assert_eq!(obj("lamp").material.emission, Vec3::new(10.0, 9.0, 8.0));
    assert_eq!(s.lights[1], Light::Point { position: Vec3::new(2.0, 3.0, 1.0), intensity: Vec3::splat(5.0) });
    let Light::Spot { position, direction, cos_inner, cos_outer, .. } = s.lights[2] else { panic!() };
    assert!(close(position, Vec3::new(0.0, 4.0, 0.0), 1e-6) && close(direction, -Vec3::Y, 1e-6));
    assert!((cos_inner - 20f32.to_radians().cos()).abs() < 1e-6 && (cos_outer - 30f32.to_radians().cos()).abs() < 1e-6);
    assert_eq!(s.ambient, Vec3::ZERO);
}

#[test]
fn repeated_shapes_share_one_mesh() {
    let mut xml = String::from("<scene>");
    for i in 0..200 {
        xml.push_str(&format!("<shape type=\"sphere\"><float name=\"radius\" value=\"{}\"/></shape>", 1 + i));
    }
    xml.push_str("<shape type=\"sphere\"><emitter type=\"area\"><rgb name=\"radiance\" value=\"2\"/></emitter></shape></scene>");
    let s = load(&[nb("many.xml", xml.as_bytes())]).unwrap();
    assert_eq!(s.objects.len(), 201, "the spheres; no floor: the file brings a light");
    let first = &s.objects[0].mesh;
    assert!(s.objects[..201].iter().all(|o| std::sync::Arc::ptr_eq(&o.mesh, first)));
    // The emitting unit sphere: one point light of the same power, Φ = L π 4π r² = 4π I.
    assert_eq!(s.lights, vec![Light::Point { position: Vec3::ZERO, intensity: Vec3::splat(2.0 * std::f32::consts::PI) }]);
}

#[test]
fn mitsuba_errors_name_the_file_and_line() {
    let err = |xml: &str| load(&[nb("bad.xml", xml.as_bytes())]).unwrap_err().to_string();
    let e = err("<scene>\n  <shape type=\"cube\">\n    <float name=\"x\" value=\"$nope\"/>\n  </shape>\n</scene>");
    assert!(e.starts_with("bad.xml:3: ") && e.contains("$nope"), "{e}");
    let e = err("<scene>\n<sensor type=\"perspective\">\n<float name=\"fov\" value=\"wide\"/>\n</sensor>\n<shape type=\"cube\"/>\n</scene>");
    assert!(e.starts_with("bad.xml:3: ") && e.contains("wide"), "{e}");
    let e = err("<scene>\n\n<shape type=\"cube\">\n<ref id=\"missing\"/>\n</shape>\n</scene>");
    assert!(e.starts_with("bad.xml:4: ") && e.contains("missing"), "{e}");
    let e = err("<scene>\n<shape type=\"cube\">\n</scene>");
    assert!(e.starts_with("bad.xml:3: ") && e.contains("XML"), "{e}");
    let e = err("<scene>\n<shape type=\"obj\">\n<string name=\"filename\" value=\"gone.obj\"/>\n</shape>\n</scene>");
    assert!(e.starts_with("bad.xml:2: ") && e.contains("gone.obj") && e.contains("not sent"), "{e}");
    let e = err("<scene>\n<shape type=\"cube\">\n<transform name=\"to_world\">\n<matrix value=\"1 2 3\"/>\n</transform>\n</shape>\n</scene>");
    assert!(e.starts_with("bad.xml:4: ") && e.contains("16"), "{e}");
    let e = err("<scene><shape type=\"cylinder\"/></scene>");
    assert!(e.contains("no (supported) shapes"), "unsupported shapes are skipped with a warning: {e}");
    // A BSDF is evaluated where a shape uses it: its bad spectrum is an error at its line.
    let used = "<scene>\n<shape type=\"cube\">\n<bsdf type=\"diffuse\">\n<spectrum name=\"reflectance\" value=\"500:1, 400:1\"/>\n</bsdf>\n</shape>\n</scene>";
    let e = err(used);
    assert!(e.starts_with("bad.xml:4: ") && e.contains("increase"), "{e}");
}

// ---------------------------------------------------------------- glTF

/// A unit quad in its local x–y plane (facing +z) with normals, UVs and u16 indices, as
/// one buffer: positions at 0, normals at 48, UVs at 96, indices at 128.
fn quad_buffer() -> Vec<u8> {
    let mut b = Vec::new();
    for p in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]] {
        p.iter().for_each(|v| b.extend(v.to_le_bytes()));
    }
    for _ in 0..4 {
        [0f32, 0.0, 1.0].iter().for_each(|v| b.extend(v.to_le_bytes()));
    }
    for uv in [[0f32, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]] {
        uv.iter().for_each(|v| b.extend(v.to_le_bytes()));
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        b.extend(i.to_le_bytes());
    }
    b.extend([0, 0, 0, 0]);
    b
}

fn gltf_json(buffer_uri: Option<&str>, len: usize, extra_images: &str) -> String {
    let uri = buffer_uri.map(|u| format!(r#""uri": "{u}", "#)).unwrap_or_default();
    format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "extensionsUsed": ["KHR_lights_punctual"],
  "extensions": {{"KHR_lights_punctual": {{"lights": [
    {{"type": "point", "color": [1, 0.5, 0.25], "intensity": 8}},
    {{"type": "spot", "intensity": 3, "spot": {{"innerConeAngle": 0.2, "outerConeAngle": 0.5}}}},
    {{"type": "directional", "intensity": 2}}
  ]}}}},
  "scene": 0,
  "scenes": [{{"nodes": [0, 3, 4, 5]}}],
  "nodes": [
    {{"name": "parent", "translation": [0, 0, -2], "children": [1, 2]}},
    {{"name": "wall", "mesh": 0, "rotation": [0, 0.7071068, 0, 0.7071068]}},
    {{"name": "lamp", "mesh": 1, "translation": [0, 2, 0], "rotation": [0.7071068, 0, 0, 0.7071068]}},
    {{"name": "cam", "camera": 0, "translation": [0, 1, 5]}},
    {{"name": "bulb", "translation": [1, 2, 3], "extensions": {{"KHR_lights_punctual": {{"light": 0}}}}, "children": [6]}},
    {{"name": "down", "rotation": [-0.7071068, 0, 0, 0.7071068], "extensions": {{"KHR_lights_punctual": {{"light": 2}}}}}},
    {{"name": "spot", "extensions": {{"KHR_lights_punctual": {{"light": 1}}}}}}
  ],
  "cameras": [{{"type": "perspective", "name": "main", "perspective": {{"yfov": 0.7, "aspectRatio": 1.5, "znear": 0.1}}}}],
  "meshes": [
    {{"name": "quad", "primitives": [{{"attributes": {{"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}}, "indices": 3, "material": 0}}]}},
    {{"name": "light", "primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 3, "material": 1}}]}}
  ],
  "materials": [
    {{"name": "paint", "doubleSided": true, "pbrMetallicRoughness": {{"baseColorFactor": [0.5, 0.25, 1, 1], "metallicFactor": 0, "roughnessFactor": 0.5 {extra_images}}}}},
    {{"name": "glow", "emissiveFactor": [1, 1, 1], "extensions": {{"KHR_materials_emissive_strength": {{"emissiveStrength": 5}}}}}}
  ],
  "buffers": [{{{uri}"byteLength": {len}}}],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": 48}},
    {{"buffer": 0, "byteOffset": 48, "byteLength": 48}},
    {{"buffer": 0, "byteOffset": 96, "byteLength": 32}},
    {{"buffer": 0, "byteOffset": 128, "byteLength": 12}}
  ],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}},
    {{"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"}},
    {{"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"}},
    {{"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}}
  ]
}}"#
    )
}

fn check_gltf_scene(s: &Scene) {
    s.validate().unwrap();
    // The camera node at (0, 1, 5) looking down its -z.
    assert!(close(s.camera.eye, Vec3::new(0.0, 1.0, 5.0), 1e-6) && close(s.camera.target, Vec3::new(0.0, 1.0, 4.0), 1e-6));
    assert!((s.camera.fov_y_degrees - 0.7f32.to_degrees()).abs() < 1e-4);
    // The wall: parent translation then its own 90° turn about y: local +z faces world +x,
    // local (1, 0, 0) lands at (0, 0, -1) - 2 z.
    let wall = s.objects.iter().find(|o| o.name == "wall").unwrap();
    let p = wall.transform.transform_point3(Vec3::X);
    assert!(close(p, Vec3::new(0.0, 0.0, -3.0), 1e-5), "{p}");
    let n = wall.transform.transform_vector3(wall.mesh.face_normals[0]).normalize();
    assert!(close(n, Vec3::X, 1e-5), "{n}");
    assert_eq!(wall.material.bsdf, Bsdf::Plastic { ior: 1.5, roughness: 0.25 });
    assert_eq!(wall.material.diffuse, Vec3::new(0.5, 0.25, 1.0));
    assert!(wall.material.two_sided);
    let c = &wall.mesh.corners;
    assert_eq!(c.normals.as_ref().unwrap()[0], [Vec3::Z; 3]);
    // UVs follow their corners: vertex 1 (1, 0, 0) has UV (1, 1).
    let t0 = wall.mesh.triangles[0];
    for (k, &v) in t0.iter().enumerate() {
        let pos = wall.mesh.positions[v as usize];
        let uv = c.uvs.as_ref().unwrap()[0][k];
        assert_eq!(uv, Vec2::new(pos.x, 1.0 - pos.y), "corner {k} at {pos}");
    }
    // Lights: the emissive quad (5 × white, facing down after +90° about x... it faces -y
    // from local +z), the point (colour × intensity), the spot under the bulb pointing
    // down its -z, and the directional light as a far point light above.
    let area: Vec<&Light> = s.lights.iter().filter(|l| matches!(l, Light::Area { .. })).collect();
    assert_eq!(area.len(), 1, "{:?}", s.lights);
    let Light::Area { radiance, .. } = area[0] else { unreachable!() };
    assert_eq!(*radiance, Vec3::splat(5.0));
    assert!(close(area[0].normal().unwrap(), -Vec3::Y, 1e-5), "{:?}", area[0].normal());
    assert!(s.lights.contains(&Light::Point { position: Vec3::new(1.0, 2.0, 3.0), intensity: Vec3::new(8.0, 4.0, 2.0) }));
    let spot = s.lights.iter().find_map(|l| match l {
        Light::Spot { position, direction, cos_inner, cos_outer, .. } => Some((*position, *direction, *cos_inner, *cos_outer)),
        _ => None,
    });
    let (pos, dir, ci, co) = spot.unwrap();
    assert!(close(pos, Vec3::new(1.0, 2.0, 3.0), 1e-6) && close(dir, -Vec3::Z, 1e-6));
    assert!((ci - 0.2f32.cos()).abs() < 1e-6 && (co - 0.5f32.cos()).abs() < 1e-6);
    // Directional: rotated -90° about x, its -z points down: the light sits far above.
    let far = s.lights.iter().find(|l| matches!(l, Light::Point { position, .. } if position.y > 1e3)).expect("distant light");
    let Light::Point { position, intensity } = far else { unreachable!() };
    let d2 = position.length_squared();
    assert!((intensity.x / d2 - 2.0).abs() < 0.01 && position.normalize().y > 0.9999, "{position} {intensity}");
    assert_eq!(s.ambient, Vec3::ZERO);
    assert!(s.objects.iter().all(|o| o.name != "floor"), "not staged");
}

#[test]
fn gltf_with_a_data_uri_buffer() {
    let buf = quad_buffer();
    let uri = format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(&buf));
    let json = gltf_json(Some(&uri), buf.len(), "");
    let s = load(&[nb("scene.gltf", json.as_bytes())]).unwrap();
    check_gltf_scene(&s);
    let v = file_view(&[nb("scene.gltf", json.as_bytes())], Some("main")).unwrap();
    assert_eq!((v.camera, v.film), (Some(s.camera), Some((768, 512))));
    let e = file_view(&[nb("scene.gltf", json.as_bytes())], Some("other")).unwrap_err().to_string();
    assert!(e.contains("other") && e.contains("main"), "{e}");
}

#[test]
fn gltf_with_an_external_buffer_and_as_glb() {
    let buf = quad_buffer();
    let json = gltf_json(Some("bin/quad%20data.bin"), buf.len(), "");
    let s = load(&[nb("scene.gltf", json.as_bytes()), nb("bin/quad data.bin", &buf)]).unwrap();
    check_gltf_scene(&s);
    let e = load(&[nb("scene.gltf", json.as_bytes())]).unwrap_err().to_string();
    assert!(e.contains("buffers[0]") && e.contains("quad data.bin") && e.contains("not sent"), "{e}");
    // The same as a GLB: JSON chunk + BIN chunk.
    let glb = load::write_glb(gltf_json(None, buf.len(), "").as_bytes(), &buf);
    check_gltf_scene(&load(&[nb("scene.glb", &glb)]).unwrap());
    // And gzipped.
    check_gltf_scene(&load(&[nb("scene.glb.gz", &gz(&glb))]).unwrap());
}

#[test]
fn gltf_base_colour_textures_are_decoded_to_linear() {
    // A 2×1 PNG: sRGB 255 and 128 grey.
    let mut png = Vec::new();
    let img = image::RgbImage::from_raw(2, 1, vec![255, 255, 255, 128, 128, 128]).unwrap();
    image::DynamicImage::ImageRgb8(img).write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).unwrap();
    let buf = quad_buffer();
    let uri = format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(&buf));
    let json = gltf_json(Some(&uri), buf.len(), r#", "baseColorTexture": {"index": 0}"#);
    let mut v: serde_json_value::Value = serde_json_value::parse(&json);
    v.add_texture();
    let json = v.0;
    let s = load(&[nb("scene.gltf", json.as_bytes()), nb("tex.png", &png)]).unwrap();
    let wall = s.objects.iter().find(|o| o.name == "wall").unwrap();
    let t = wall.material.texture.as_ref().expect("texture");
    assert_eq!((t.width, t.height), (2, 1));
    assert!((t.texels[0].x - 1.0).abs() < 1e-6);
    // sRGB 128/255 = 0.50196 is 0.21586 linear.
    assert!((t.texels[1].x - 0.21586).abs() < 1e-4, "{}", t.texels[1]);
}

/// Adds `textures` and `images` arrays to the test glTF (text edit: no JSON crate here).
mod serde_json_value {
    pub struct Value(pub String);
    pub fn parse(s: &str) -> Value {
        Value(s.to_string())
    }
    impl Value {
        pub fn add_texture(&mut self) {
            let at = self.0.rfind('}').unwrap();
            self.0.insert_str(at, r#", "textures": [{"source": 0}], "images": [{"uri": "tex.png"}]"#);
        }
    }
}

#[test]
fn gltf_errors_name_the_file_and_json_path_or_line() {
    let buf = quad_buffer();
    let uri = format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(&buf));
    let good = gltf_json(Some(&uri), buf.len(), "");
    let err = |json: &str| load(&[nb("bad.gltf", json.as_bytes())]).unwrap_err().to_string();
    // JSON syntax: the line.
    let e = err("{\n  \"asset\": {\"version\": \"2.0\"},\n  \"nodes\": [,]\n}");
    assert!(e.starts_with("bad.gltf:3: ") && e.contains("JSON"), "{e}");
    // An index past the vertices: the primitive's JSON path.
    let mut bad_idx = buf.clone();
    bad_idx[128..130].copy_from_slice(&9u16.to_le_bytes());
    let u2 = format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(&bad_idx));
    let e = err(&good.replace(&uri, &u2));
    assert!(e.contains("bad.gltf") && e.contains("meshes[0].primitives[0].indices") && e.contains("9"), "{e}");
    // An accessor claiming more elements than its view holds: refused before reading.
    let e = err(&good.replace(r#""componentType": 5126, "count": 4, "type": "VEC3", "min""#, r#""componentType": 5126, "count": 4000000000, "type": "VEC3", "min""#));
    assert!(e.contains("bad.gltf") && e.contains("POSITION"), "{e}");
    // A buffer shorter than its byteLength.
    let e = err(&good.replace(&format!(r#""byteLength": {}}}"#, buf.len()), r#""byteLength": 100000}"#));
    assert!(e.contains("buffers[0]") && e.contains("100000"), "{e}");
    // Invalid references: the validator's JSON path.
    let e = err(&good.replace(r#""mesh": 0,"#, r#""mesh": 7,"#));
    assert!(e.contains("bad.gltf") && e.contains("nodes[1].mesh"), "{e}");
}

// ---------------------------------------------------------------- OBJ, gzip, gathering

#[test]
fn obj_normals_and_uvs_become_corner_attributes() {
    let obj = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nvn 0 0.6 0.8\n\
f 1/1/1 2/2/1 3/3/2 4/4/2\nf 1 3 2\n";
    let s = load(&[nb("q.obj", obj)]).unwrap();
    let m = &s.objects[0].mesh;
    assert_eq!(m.triangles.len(), 3);
    let (n, uv) = (m.corners.normals.as_ref().unwrap(), m.corners.uvs.as_ref().unwrap());
    // Oracle: each corner's attributes are those of its file vertex (v i ↔ vt i here).
    let file_uv = [Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)];
    let file_pos = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
    for f in 0..2 {
        for k in 0..3 {
            let p = m.positions[m.triangles[f][k] as usize];
            let i = file_pos.iter().position(|q| *q == p).unwrap();
            assert_eq!(uv[f][k], file_uv[i]);
            let want = if i < 2 { Vec3::Z } else { Vec3::new(0.0, 0.6, 0.8) };
            assert!(close(n[f][k], want, 1e-6), "{f} {k}");
        }
    }
    // The face without attributes gets zeros (no normal, UV 0).
    assert_eq!(n[2], [Vec3::ZERO; 3]);
    let e = load(&[nb("q.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//2 3//1\n")]).unwrap_err().to_string();
    assert!(e.starts_with("q.obj:5: ") && e.contains("normal 2"), "{e}");
    let e = load(&[nb("q.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/4 2/1 3/1\n")]).unwrap_err().to_string();
    assert!(e.starts_with("q.obj:4: ") && e.contains("texture coordinate 4"), "{e}");
}

#[test]
fn gz_obj_and_ply_load_like_the_plain_files() {
    let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    let plain = load(&[nb("t.obj", obj)]).unwrap();
    let zipped = load(&[nb("t.obj.gz", &gz(obj))]).unwrap();
    assert_eq!(plain.objects[0].mesh.positions, zipped.objects[0].mesh.positions);
    assert_eq!(plain.objects[0].mesh.triangles, zipped.objects[0].mesh.triangles);
    let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let a = load(&[nb("t.ply", ply)]).unwrap();
    let b = load(&[nb("T.PLY.GZ", &gz(ply))]).unwrap();
    assert_eq!(a.objects[0].mesh.positions, b.objects[0].mesh.positions);
    // A broken gzip names the file; a gzip of a bad PLY names the inner file and line.
    let e = load(&[nb("x.ply.gz", b"\x1f\x8bjunk")]).unwrap_err().to_string();
    assert!(e.starts_with("x.ply.gz: ") && e.contains("gzip"), "{e}");
    let e = load(&[nb("y.obj.gz", &gz(b"v 0 0 0\nv oops 0 0\n"))]).unwrap_err().to_string();
    assert!(e.starts_with("y.obj:2: "), "{e}");
}

#[test]
fn referenced_files_are_gathered_safely_for_every_format() {
    let dir = std::env::temp_dir().join(format!("edgepoint-gather-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("scene/meshes")).unwrap();
    let tri = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    std::fs::write(dir.join("scene/meshes/a.obj"), tri).unwrap();
    std::fs::write(dir.join("scene/meshes/b.obj.gz"), gz(tri)).unwrap();
    std::fs::write(dir.join("secret.obj"), tri).unwrap();
    let xml = r#"<scene>
<default name="m" value="meshes"/>
<shape type="obj"><string name="filename" value="$m/a.obj"/></shape>
<shape type="obj"><string name="filename" value="meshes/b.obj"/></shape>
<shape type="obj"><string name="filename" value="../secret.obj"/></shape>
<shape type="obj"><string name="filename" value="/etc/passwd"/></shape>
</scene>"#;
    std::fs::write(dir.join("scene/s.xml"), xml).unwrap();
    let files = gather(&dir.join("scene/s.xml")).unwrap();
    let names: Vec<&str> = files.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["s.xml", "meshes/a.obj", "meshes/b.obj.gz"], "nothing outside the scene's directory");
    let e = load_path(&dir.join("scene/s.xml"), &NoProgress).unwrap_err().to_string();
    assert!(e.starts_with("s.xml:5: ") && e.contains("../secret.obj"), "a mesh it may not send is an error at its line: {e}");
    // glTF: its external buffer.
    let buf = quad_buffer();
    std::fs::write(dir.join("scene/q.bin"), &buf).unwrap();
    std::fs::write(dir.join("scene/q.gltf"), gltf_json(Some("q.bin"), buf.len(), "")).unwrap();
    let s = load_path(&dir.join("scene/q.gltf"), &NoProgress).unwrap();
    check_gltf_scene(&s);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn staging_is_only_for_bare_models() {
    let tri = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    let bare = load(&[nb("t.obj", tri)]).unwrap();
    assert!(bare.objects.iter().any(|o| o.name == "floor") && bare.lights.len() == 1);
    assert_eq!(bare.ambient, Vec3::splat(load::STAGED_AMBIENT));
    // An OBJ with an emissive material brings its light: no floor, no added light, no ambient.
    let lit = b"mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 2 0\nv 1 2 0\nv 0 2 1\nusemtl white\nf 1 2 3\nusemtl lamp\nf 4 6 5\n";
    let mtl = b"newmtl white\nKd 0.8 0.8 0.8\nnewmtl lamp\nKe 5 5 5\n";
    let s = load(&[nb("l.obj", lit), nb("m.mtl", mtl)]).unwrap();
    assert!(s.objects.iter().all(|o| o.name != "floor"));
    assert_eq!((s.lights.len(), s.ambient), (1, Vec3::ZERO));
}

#[test]
fn a_reflectance_spectrum_and_an_emitter_spectrum_differ_by_d65() {
    let flat = [(360.0, 1.0), (830.0, 1.0)];
    let r = spectrum::spectrum_to_rgb(&flat, spectrum::SpectrumKind::Reflectance);
    let e = spectrum::spectrum_to_rgb(&flat, spectrum::SpectrumKind::Emitter);
    assert!(close(r, Vec3::ONE, 5e-3), "{r}");
    // The emitter is the flat spectrum itself: XYZ (1, 1, 1), whose sRGB is
    // (1.2048, 0.9484, 0.9086) — the Rec. 709 matrix's row sums.
    assert!(close(e, Vec3::new(1.204794, 0.948291, 0.908916), 5e-3), "{e}");
}
