//! glTF 2.0 scenes (`.gltf` with its buffers and images among the scene's files, or
//! `.glb`), read with the `gltf` crate:
//!
//! - the default scene's node hierarchy and transforms; every triangle primitive (lists,
//!   strips and fans) becomes an object, with `NORMAL` and `TEXCOORD_0` as corner attributes;
//! - the first perspective camera met in the hierarchy (or the one named with
//!   `--camera-name`: camera or node name);
//! - `KHR_lights_punctual`: point and spot lights as they are, directional lights as a point
//!   light far away (with a warning: there are no lights at infinity); intensities are taken
//!   as radiometric (candela as W/sr, lux as W/m²);
//! - metallic-roughness materials mapped to the nearest [`Bsdf`]: metallic → a conductor
//!   reflecting the base colour, otherwise plastic (diffuse base colour under an index-1.5
//!   coat), GGX alpha = roughness²; base-colour textures decoded from sRGB to linear;
//!   `emissiveFactor` (× `KHR_materials_emissive_strength`) makes the primitive an area light.
//!
//! Buffers and images come from data URIs, the GLB binary chunk, or the scene's files —
//! never the disk. Every accessor is checked against the bytes behind it before it is read,
//! so no count the file claims sizes an allocation. Errors name the file and a JSON path
//! (`meshes[0].primitives[1].indices`) or line.
use super::emitters::area_lights;
use super::files::{find, Reference};
use super::{stage_meshes, FileView, NamedBytes};
use crate::{Bsdf, Camera, Corners, Light, Material, Mesh, Object, Progress, Scene, SceneError, Texture};
use ::gltf::accessor::{DataType, Dimensions};
use ::gltf::{khr_lights_punctual::Kind as LightKind, mesh::Mode, Document, Gltf};
use base64::Engine;
use glam::{Affine3A, Mat4, Vec2, Vec3};
use std::collections::HashMap;
use std::sync::Arc;

/// Deepest node hierarchy followed (glTF forbids cycles; a file that has one is refused
/// here instead of overflowing the stack).
const MAX_DEPTH: usize = 256;
/// Largest texture side kept; larger images are reduced (with a warning).
const MAX_TEXTURE_SIDE: u32 = 4096;
/// Most elements one accessor may have.
const MAX_ACCESSOR_COUNT: usize = 1 << 28;

/// Parses and validates a glTF. The crate's validator indexes the accessor list with a
/// primitive's POSITION index unchecked, so that index is checked first (a fuzzed file
/// made it panic).
fn parse(name: &str, data: &[u8]) -> Result<Gltf, SceneError> {
    use ::gltf::json::validation::Validate;
    let g = Gltf::from_slice_without_validation(data).map_err(|e| gltf_error(name, e))?;
    let json = g.as_json();
    for (i, m) in json.meshes.iter().enumerate() {
        for (j, p) in m.primitives.iter().enumerate() {
            for (sem, acc) in &p.attributes {
                if acc.value() >= json.accessors.len() {
                    let sem = match sem {
                        ::gltf::json::validation::Checked::Valid(s) => s.to_string(),
                        _ => "?".into(),
                    };
                    return Err(SceneError::file(
                        name,
                        format!("meshes[{i}].primitives[{j}].attributes.{sem}: accessor {} does not exist ({} accessors)", acc.value(), json.accessors.len()),
                    ));
                }
            }
        }
    }
    let mut errors = Vec::new();
    json.validate(json, ::gltf::json::Path::new, &mut |path, error| errors.push((path(), error)));
    if !errors.is_empty() {
        return Err(gltf_error(name, ::gltf::Error::Validation(errors)));
    }
    Ok(g)
}

fn gltf_error(name: &str, e: ::gltf::Error) -> SceneError {
    match e {
        ::gltf::Error::Deserialize(j) => SceneError::line(name, j.line(), format!("JSON: {j}")),
        ::gltf::Error::Validation(errs) => {
            let list: Vec<String> = errs.iter().take(5).map(|(path, err)| format!("{path}: {err}")).collect();
            let more = if errs.len() > 5 { format!(" (and {} more)", errs.len() - 5) } else { String::new() };
            SceneError::file(name, format!("invalid glTF: {}{more}", list.join("; ")))
        }
        other => SceneError::file(name, format!("invalid glTF: {other}")),
    }
}

/// `%XX` escapes of a URI decoded (glTF URIs are percent-encoded file names).
fn percent_decode(uri: &str) -> String {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            if let Some(v) = std::str::from_utf8(&b[i + 1..i + 3]).ok().and_then(|h| u8::from_str_radix(h, 16).ok()) {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn is_file_uri(uri: &str) -> bool {
    !uri.starts_with("data:") && !uri.contains("://")
}

/// A GLB container of `json` and the binary chunk `bin` (JSON padded with spaces, BIN
/// with zeros, to 4 bytes, as the format requires). For tests and benchmarks that write
/// scenes.
pub fn write_glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |n: usize| (4 - n % 4) % 4;
    let (jl, bl) = (json.len() + pad(json.len()), bin.len() + pad(bin.len()));
    let mut out = Vec::with_capacity(28 + jl + bl);
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend(((12 + 8 + jl + 8 + bl) as u32).to_le_bytes());
    out.extend((jl as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(json);
    out.extend(std::iter::repeat_n(b' ', jl - json.len()));
    out.extend((bl as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(bin);
    out.extend(std::iter::repeat_n(0u8, bl - bin.len()));
    out
}

/// Every file a glTF names: its buffers' and images' URIs that are not data URIs.
pub fn references(data: &[u8]) -> Vec<Reference> {
    let Ok(g) = Gltf::from_slice_without_validation(data) else { return Vec::new() };
    let buffers = g.buffers().filter_map(|b| match b.source() {
        ::gltf::buffer::Source::Uri(u) => Some(u),
        _ => None,
    });
    let images = g.images().filter_map(|i| match i.source() {
        ::gltf::image::Source::Uri { uri, .. } => Some(uri),
        _ => None,
    });
    buffers.chain(images).filter(|u| is_file_uri(u)).map(|u| Reference { line: 0, name: percent_decode(u) }).collect()
}

/// The bytes of a data URI (`data:...;base64,...`).
fn data_uri(name: &str, path: &str, uri: &str) -> Result<Vec<u8>, SceneError> {
    let (_, payload) = uri.split_once(',').ok_or_else(|| SceneError::file(name, format!("{path}: data URI without a comma")))?;
    if !uri[..uri.len() - payload.len()].contains(";base64") {
        return Ok(percent_decode(payload).into_bytes());
    }
    base64::engine::general_purpose::STANDARD
        .decode(payload.trim())
        .map_err(|e| SceneError::file(name, format!("{path}: data URI is not valid base64: {e}")))
}

/// The bytes behind a URI: a data URI or one of the scene's files.
fn uri_bytes(name: &str, files: &[NamedBytes], path: &str, uri: &str) -> Result<Vec<u8>, SceneError> {
    if uri.starts_with("data:") {
        return data_uri(name, path, uri);
    }
    if !is_file_uri(uri) {
        return Err(SceneError::file(name, format!("{path}: `{uri}` is not a file (only data URIs and relative file names are read)")));
    }
    let file = percent_decode(uri);
    let f = find(files, &file)
        .ok_or_else(|| SceneError::file(name, format!("{path}: {file} was not sent with the scene (is it next to the glTF file, inside its directory?)")))?;
    Ok(super::files::ungzip(f)?.data.clone())
}

/// The bytes of every buffer; the GLB binary chunk is moved out of `g`, not copied.
fn buffers(name: &str, g: &mut Gltf, files: &[NamedBytes]) -> Result<Vec<Vec<u8>>, SceneError> {
    let mut blob = g.blob.take();
    let mut out = Vec::new();
    for b in g.buffers() {
        let path = format!("buffers[{}]", b.index());
        let data = match b.source() {
            ::gltf::buffer::Source::Bin => {
                blob.take().ok_or_else(|| SceneError::file(name, format!("{path}: refers to the GLB binary chunk, which the file lacks (or another buffer took it)")))?
            }
            ::gltf::buffer::Source::Uri(uri) => uri_bytes(name, files, &path, uri)?,
        };
        if data.len() < b.length() {
            return Err(SceneError::file(name, format!("{path}: has {} bytes but byteLength says {}", data.len(), b.length())));
        }
        out.push(data);
    }
    Ok(out)
}

/// Whether an accessor can be read from `buffers` without trusting its count: a dense
/// accessor of at least one element whose every byte is in its buffer view and buffer.
fn readable(acc: &::gltf::Accessor, buffers: &[Vec<u8>], types: &[DataType], dims: Dimensions) -> Result<(), String> {
    // The reader assumes these (it reaches `unreachable!` or misreads otherwise).
    if !types.contains(&acc.data_type()) || acc.dimensions() != dims {
        return Err(format!("component type {:?} {:?} where {types:?} {dims:?} is required", acc.data_type(), acc.dimensions()));
    }
    if acc.sparse().is_some() {
        return Err("sparse accessors are not supported".into());
    }
    let n = acc.count();
    if n == 0 || n > MAX_ACCESSOR_COUNT {
        return Err(format!("count {n} is not in 1..={MAX_ACCESSOR_COUNT}"));
    }
    let view = acc.view().ok_or("accessor has no buffer view (all zeros)")?;
    let size = acc.size();
    let stride = view.stride().unwrap_or(size).max(size);
    let need = acc.offset() as u64 + stride as u64 * (n as u64 - 1) + size as u64;
    if need > view.length() as u64 {
        return Err(format!("needs {need} bytes of its buffer view, which has {}", view.length()));
    }
    let end = view.offset() as u64 + view.length() as u64;
    let have = buffers.get(view.buffer().index()).map_or(0, |b| b.len()) as u64;
    if end > have {
        return Err(format!("its buffer view ends at byte {end} of a buffer of {have}"));
    }
    Ok(())
}

/// Decodes an image file (PNG, JPEG) into a linear texture: `srgb` converts 8-bit sRGB to
/// linear; `flip_rows` puts the image's bottom row at v = 0 (OBJ / Mitsuba UVs; glTF's v
/// runs down the image, so glTF textures are not flipped). Images larger than
/// [`MAX_TEXTURE_SIDE`] are reduced.
pub fn decode_texture(file: &NamedBytes, srgb: bool, flip_rows: bool) -> Result<Texture, SceneError> {
    decode_image_bytes(&file.name, &file.data, srgb, flip_rows)
}

fn decode_image_bytes(name: &str, data: &[u8], srgb: bool, flip_rows: bool) -> Result<Texture, SceneError> {
    let mut reader = image::ImageReader::new(std::io::Cursor::new(data))
        .with_guessed_format()
        .map_err(|e| SceneError::file(name, format!("cannot read image: {e}")))?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(16384);
    limits.max_image_height = Some(16384);
    limits.max_alloc = Some(1 << 30);
    reader.limits(limits);
    let mut img = reader.decode().map_err(|e| SceneError::file(name, format!("cannot decode image: {e}")))?;
    if img.width() > MAX_TEXTURE_SIDE || img.height() > MAX_TEXTURE_SIDE {
        tracing::warn!("{name}: {}x{} texture reduced to fit {MAX_TEXTURE_SIDE}x{MAX_TEXTURE_SIDE}", img.width(), img.height());
        img = img.resize(MAX_TEXTURE_SIDE, MAX_TEXTURE_SIDE, image::imageops::FilterType::Triangle);
    }
    if flip_rows {
        img = img.flipv();
    }
    let rgb = img.to_rgb8();
    let lut: Vec<f32> = (0..256).map(|v| if srgb { srgb_to_linear(v as f32 / 255.0) } else { v as f32 / 255.0 }).collect();
    let texels = rgb.pixels().map(|p| Vec3::new(lut[p[0] as usize], lut[p[1] as usize], lut[p[2] as usize])).collect();
    Ok(Texture { name: name.to_string(), width: rgb.width(), height: rgb.height(), texels })
}

/// The sRGB transfer function inverted (IEC 61966-2-1).
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The world transform of every node of the default (or first) scene, in hierarchy order.
fn world_nodes<'a>(name: &str, doc: &'a Document) -> Result<Vec<(::gltf::Node<'a>, Mat4)>, SceneError> {
    let Some(scene) = doc.default_scene().or_else(|| doc.scenes().next()) else {
        return Ok(Vec::new());
    };
    let mut out = Vec::new();
    let mut stack: Vec<(::gltf::Node, Mat4, usize)> = scene.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect();
    stack.reverse();
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > MAX_DEPTH {
            return Err(SceneError::file(name, format!("nodes[{}]: node hierarchy deeper than {MAX_DEPTH} (a cycle?)", node.index())));
        }
        let m = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if !m.is_finite() {
            return Err(SceneError::file(name, format!("nodes[{}]: transform is not finite", node.index())));
        }
        let mut children: Vec<_> = node.children().map(|c| (c, m, depth + 1)).collect();
        children.reverse();
        stack.extend(children);
        out.push((node, m));
    }
    Ok(out)
}

/// The camera of a node: glTF cameras look down their local -Z with +Y up.
fn node_camera(name: &str, node: &::gltf::Node, m: &Mat4) -> Option<(Camera, Option<f32>)> {
    let cam = node.camera()?;
    match cam.projection() {
        ::gltf::camera::Projection::Perspective(p) => {
            let eye = m.transform_point3(Vec3::ZERO);
            let dir = m.transform_vector3(-Vec3::Z).normalize_or_zero();
            let up = m.transform_vector3(Vec3::Y).normalize_or_zero();
            Some((Camera { eye, target: eye + dir, up, fov_y_degrees: p.yfov().to_degrees() }, p.aspect_ratio()))
        }
        ::gltf::camera::Projection::Orthographic(_) => {
            tracing::warn!("{name}: cameras[{}] is orthographic, which is not supported: skipped", cam.index());
            None
        }
    }
}

/// The first perspective camera, or the one whose camera or node name is `want`.
fn pick_camera(name: &str, nodes: &[(::gltf::Node, Mat4)], want: Option<&str>) -> Result<Option<(Camera, Option<f32>)>, SceneError> {
    let mut names = Vec::new();
    for (node, m) in nodes {
        let Some(cam) = node.camera() else { continue };
        let cam_name = cam.name().unwrap_or("");
        let node_name = node.name().unwrap_or("");
        names.push(if cam_name.is_empty() { node_name.to_string() } else { cam_name.to_string() });
        if want.is_some_and(|w| w != cam_name && w != node_name) {
            continue;
        }
        if let Some(c) = node_camera(name, node, m) {
            c.0.validate().map_err(|e| SceneError::file(name, format!("nodes[{}] camera: {e}", node.index())))?;
            return Ok(Some(c));
        }
    }
    match want {
        Some(w) => Err(SceneError::file(
            name,
            format!("--camera-name {w}: no perspective camera of that name (cameras: {})", if names.is_empty() { "none".into() } else { names.join(", ") }),
        )),
        None => Ok(None),
    }
}

/// The camera (and the film aspect its aspect ratio implies, 512 pixels high) of a glTF.
pub fn view(main: &NamedBytes, _files: &[NamedBytes], camera_name: Option<&str>) -> Result<FileView, SceneError> {
    let g = parse(&main.name, &main.data)?;
    let nodes = world_nodes(&main.name, &g)?;
    Ok(match pick_camera(&main.name, &nodes, camera_name)? {
        Some((camera, aspect)) => FileView {
            camera: Some(camera),
            film: aspect.filter(|a| a.is_finite() && *a > 0.01 && *a < 100.0).map(|a| (((512.0 * a).round() as u32).clamp(1, 16384), 512)),
        },
        None => FileView::default(),
    })
}

/// What a glTF material becomes: the material, and its emitted radiance.
fn material(name: &str, m: &::gltf::Material, images: &mut ImageCache) -> Result<Material, SceneError> {
    let path = match m.index() {
        Some(i) => format!("materials[{i}]"),
        None => "default material".into(),
    };
    let pbr = m.pbr_metallic_roughness();
    let [r, g, b, _] = pbr.base_color_factor();
    let diffuse = Vec3::new(r, g, b).clamp(Vec3::ZERO, Vec3::ONE);
    let texture = match pbr.base_color_texture() {
        Some(info) => {
            if info.tex_coord() != 0 {
                tracing::warn!("{name}: {path}: base colour texture uses TEXCOORD_{}; only TEXCOORD_0 is read", info.tex_coord());
            }
            images.get(info.texture().source().index())?
        }
        None => None,
    };
    if pbr.metallic_roughness_texture().is_some() {
        tracing::warn!("{name}: {path}: metallic-roughness texture not supported: its factors are used alone");
    }
    if m.normal_texture().is_some() || m.occlusion_texture().is_some() {
        tracing::warn!("{name}: {path}: normal / occlusion textures are not supported: ignored");
    }
    if m.alpha_mode() != ::gltf::material::AlphaMode::Opaque {
        tracing::warn!("{name}: {path}: alpha mode {:?} is not supported: rendered opaque", m.alpha_mode());
    }
    let metallic = pbr.metallic_factor();
    let alpha = pbr.roughness_factor().clamp(0.0, 1.0).powi(2);
    if metallic > 0.0 && metallic < 1.0 {
        tracing::warn!("{name}: {path}: metallic {metallic} between 0 and 1 is rounded to {}", if metallic >= 0.5 { "a metal" } else { "a dielectric" });
    }
    let bsdf = if metallic >= 0.5 {
        // A metal reflecting its base colour at every angle: Fresnel of index 0 + 1i is 1.
        Bsdf::Conductor { eta: Vec3::ZERO, k: Vec3::ONE, roughness: alpha }
    } else {
        Bsdf::Plastic { ior: 1.5, roughness: alpha }
    };
    let strength = m.emissive_strength().unwrap_or(1.0);
    let emission = Vec3::from(m.emissive_factor()) * strength;
    if m.emissive_texture().is_some() {
        tracing::warn!("{name}: {path}: emissive texture not supported: emissiveFactor alone is used");
    }
    if !(emission.is_finite() && emission.min_element() >= 0.0) {
        return Err(SceneError::file(name, format!("{path}: emission {emission} is not finite and non-negative")));
    }
    Ok(Material {
        name: m.name().map(str::to_string).unwrap_or(path),
        diffuse,
        texture,
        bsdf,
        two_sided: m.double_sided(),
        emission,
    })
}

/// Decoded images by index, each decoded once.
struct ImageCache<'a> {
    name: &'a str,
    doc: &'a Document,
    buffers: &'a [Vec<u8>],
    files: &'a [NamedBytes],
    done: HashMap<usize, Option<Arc<Texture>>>,
}

impl ImageCache<'_> {
    fn get(&mut self, index: usize) -> Result<Option<Arc<Texture>>, SceneError> {
        if let Some(t) = self.done.get(&index) {
            return Ok(t.clone());
        }
        let path = format!("images[{index}]");
        let image = self.doc.images().nth(index).ok_or_else(|| SceneError::file(self.name, format!("{path} does not exist")))?;
        let bytes = match image.source() {
            ::gltf::image::Source::View { view, .. } => {
                let b = self.buffers.get(view.buffer().index()).map(Vec::as_slice).unwrap_or(&[]);
                b.get(view.offset()..view.offset() + view.length())
                    .ok_or_else(|| SceneError::file(self.name, format!("{path}: its buffer view is outside its buffer")))?
                    .to_vec()
            }
            ::gltf::image::Source::Uri { uri, .. } => uri_bytes(self.name, self.files, &path, uri)?,
        };
        let t = decode_image_bytes(&format!("{} {path}", self.name), &bytes, true, false).map(Arc::new)?;
        self.done.insert(index, Some(t.clone()));
        Ok(Some(t))
    }
}

/// The triangles of a primitive as index triples (lists, strips, fans).
fn primitive_triangles(mode: Mode, idx: &[u32]) -> Option<Vec<[u32; 3]>> {
    Some(match mode {
        Mode::Triangles => idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        Mode::TriangleStrip => (2..idx.len())
            .map(|i| if i % 2 == 0 { [idx[i - 2], idx[i - 1], idx[i]] } else { [idx[i - 1], idx[i - 2], idx[i]] })
            .collect(),
        Mode::TriangleFan => (2..idx.len()).map(|i| [idx[0], idx[i - 1], idx[i]]).collect(),
        _ => return None,
    })
}

/// The mesh of one triangle primitive (`None`, with a warning, for points and lines or a
/// primitive without positions).
fn primitive_mesh(
    name: &str,
    path: &str,
    prim: &::gltf::Primitive,
    buffers: &[Vec<u8>],
    progress: &dyn Progress,
) -> Result<Option<Mesh>, SceneError> {
    let reader = prim.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
    let Some(pos_acc) = prim.get(&::gltf::Semantic::Positions) else {
        tracing::warn!("{name}: {path}: no POSITION: skipped");
        return Ok(None);
    };
    if let Err(e) = readable(&pos_acc, buffers, &[DataType::F32], Dimensions::Vec3) {
        return Err(SceneError::file(name, format!("{path}.attributes.POSITION: {e}")));
    }
    let positions: Vec<Vec3> = reader.read_positions().map(|p| p.map(Vec3::from).collect()).unwrap_or_default();
    for (i, p) in positions.iter().enumerate() {
        crate::limits::check_vec(&format!("vertex {i}"), *p, crate::limits::MAX_COORDINATE)
            .map_err(|e| SceneError::file(name, format!("{path}.attributes.POSITION: {e}")))?;
    }
    let indices: Vec<u32> = match prim.indices() {
        Some(acc) => {
            readable(&acc, buffers, &[DataType::U8, DataType::U16, DataType::U32], Dimensions::Scalar)
                .map_err(|e| SceneError::file(name, format!("{path}.indices: {e}")))?;
            reader.read_indices().map(|i| i.into_u32().collect()).unwrap_or_default()
        }
        None => (0..positions.len() as u32).collect(),
    };
    if let Some(bad) = indices.iter().find(|&&i| i as usize >= positions.len()) {
        return Err(SceneError::file(name, format!("{path}.indices: index {bad} but only {} vertices", positions.len())));
    }
    let Some(tris) = primitive_triangles(prim.mode(), &indices) else {
        tracing::warn!("{name}: {path}: mode {:?} (points or lines) is not a surface: skipped", prim.mode());
        return Ok(None);
    };
    let attr = |sem: ::gltf::Semantic, what: &str, types: &[DataType], dims: Dimensions| -> Result<bool, SceneError> {
        match prim.get(&sem) {
            None => Ok(false),
            Some(acc) => match readable(&acc, buffers, types, dims) {
                Ok(()) if acc.count() == positions.len() => Ok(true),
                Ok(()) => Err(SceneError::file(name, format!("{path}.attributes.{what}: {} entries for {} vertices", acc.count(), positions.len()))),
                Err(e) => Err(SceneError::file(name, format!("{path}.attributes.{what}: {e}"))),
            },
        }
    };
    let normals: Option<Vec<Vec3>> = if attr(::gltf::Semantic::Normals, "NORMAL", &[DataType::F32], Dimensions::Vec3)? {
        reader.read_normals().map(|n| n.map(|v| Vec3::from(v).normalize_or_zero()).collect())
    } else {
        None
    };
    let uvs: Option<Vec<Vec2>> = if attr(::gltf::Semantic::TexCoords(0), "TEXCOORD_0", &[DataType::F32, DataType::U8, DataType::U16], Dimensions::Vec2)? {
        reader.read_tex_coords(0).map(|t| t.into_f32().map(Vec2::from).collect())
    } else {
        None
    };
    let corners = Corners {
        normals: normals.map(|n| tris.iter().map(|t| t.map(|i| n[i as usize])).collect()),
        uvs: uvs.map(|u| tris.iter().map(|t| t.map(|i| u[i as usize])).collect()),
    };
    let mesh = Mesh::from_triangles_with_corners(positions, tris, corners, progress);
    Ok((!mesh.triangles.is_empty()).then_some(mesh))
}

/// Loads a glTF 2.0 scene; `files` are the scene's files (main first).
pub fn load(main: &NamedBytes, files: &[NamedBytes], progress: &dyn Progress) -> Result<Scene, SceneError> {
    let name = main.name.as_str();
    let mut g = parse(name, &main.data)?;
    let buffers = buffers(name, &mut g, files)?;
    let nodes = world_nodes(name, &g)?;
    let camera = pick_camera(name, &nodes, None)?.map(|c| c.0);
    let mut images = ImageCache { name, doc: &g, buffers: &buffers, files, done: HashMap::new() };
    let mut materials: HashMap<Option<usize>, Material> = HashMap::new();
    let mut objects = Vec::new();
    let mut lights = Vec::new();
    let mut directional = Vec::new();
    let mut prim_meshes: HashMap<(usize, usize), Option<Arc<Mesh>>> = HashMap::new();
    for (node, m) in &nodes {
        let transform = Affine3A::from_mat4(*m);
        if let Some(light) = node.light() {
            let intensity = Vec3::from(light.color()) * light.intensity();
            let path = format!("nodes[{}] light {}", node.index(), light.index());
            if !(intensity.is_finite() && intensity.min_element() >= 0.0) {
                return Err(SceneError::file(name, format!("{path}: intensity {intensity} is not finite and non-negative")));
            }
            let position = transform.transform_point3(Vec3::ZERO);
            let direction = transform.transform_vector3(-Vec3::Z).normalize_or_zero();
            match light.kind() {
                LightKind::Point => lights.push(Light::Point { position, intensity }),
                LightKind::Spot { inner_cone_angle, outer_cone_angle } => {
                    let outer = outer_cone_angle.clamp(0.0, std::f32::consts::FRAC_PI_2);
                    lights.push(Light::Spot {
                        position,
                        direction,
                        intensity,
                        cos_inner: inner_cone_angle.clamp(0.0, outer).cos(),
                        cos_outer: outer.cos(),
                    })
                }
                LightKind::Directional => {
                    tracing::warn!("{name}: {path}: directional light approximated by a point light far away in its direction (edgepoint has no lights at infinity)");
                    directional.push((direction, intensity));
                }
            }
            if light.range().is_some() {
                tracing::warn!("{name}: {path}: light range is not supported: the light reaches everywhere");
            }
        }
        let Some(mesh) = node.mesh() else { continue };
        crate::limits::check_affine(&transform).map_err(|e| SceneError::file(name, format!("nodes[{}]: {e}", node.index())))?;
        for prim in mesh.primitives() {
            let path = format!("meshes[{}].primitives[{}]", mesh.index(), prim.index());
            // A mesh used by several nodes is built once and shared.
            let key = (mesh.index(), prim.index());
            let mesh_data = match prim_meshes.get(&key) {
                Some(m) => m.clone(),
                None => {
                    let m = primitive_mesh(name, &path, &prim, &buffers, progress)?.map(Arc::new);
                    prim_meshes.insert(key, m.clone());
                    m
                }
            };
            let Some(mesh_data) = mesh_data else { continue };
            let material = match materials.get(&prim.material().index()) {
                Some(m) => m.clone(),
                None => {
                    let m = material(name, &prim.material(), &mut images)?;
                    materials.insert(prim.material().index(), m.clone());
                    m
                }
            };
            if material.emission.max_element() > 0.0 {
                let world: Vec<[Vec3; 3]> =
                    (0..mesh_data.triangles.len()).map(|f| mesh_data.triangle(f).map(|p| transform.transform_point3(p))).collect();
                lights.extend(area_lights(&format!("{name}: {path}"), &world, material.emission));
            }
            let obj_name = match (node.name(), mesh.name()) {
                (Some(n), _) if mesh.primitives().len() == 1 => n.to_string(),
                (Some(n), _) => format!("{n}:{}", prim.index()),
                (None, Some(m)) => format!("{m}:{}", prim.index()),
                (None, None) => path.clone(),
            };
            objects.push(Object { name: obj_name, mesh: mesh_data, material, transform });
        }
    }
    if objects.is_empty() {
        return Err(SceneError::file(name, "the glTF's scene has no triangle meshes"));
    }
    for (dir, irradiance) in directional {
        lights.push(super::mitsuba::distant_light(dir, irradiance, &objects));
    }
    if lights.len() > 64 {
        tracing::warn!("{name}: {} lights (emissive triangles merge into at most one light per convex polygon); each costs shadow rays per sample", lights.len());
    }
    Ok(stage_meshes(&super::stem(name), objects, lights, camera))
}
