//! Scene files. Formats: PLY (binary and ASCII), OBJ (+MTL), Mitsuba 3 XML and glTF 2.0
//! (`.gltf` + buffers, `.glb`), each in its module; `.gz` versions of any of them. A scene
//! travels as its files' bytes ([`NamedBytes`], main file first), gathered from disk by
//! [`gather`] and resolved by the loaders with [`files::find`]. A file that brings no lights
//! or camera (every PLY, most OBJs) is staged by [`stage_meshes`]: the model on a floor under
//! a point light, framed by the camera; one that brings its own is taken as it is.
mod emitters;
pub mod files;
mod gltf;
mod mitsuba;
mod obj;
mod ply;
pub mod spectrum;
mod stage;

pub use files::{gather, reference_path, references, Reference};
pub use gltf::write_glb;
pub use obj::mtllib_names;
pub use stage::{stage_meshes, STAGED_AMBIENT};

use crate::{Camera, Light, Material, Mesh, Object, Progress, Scene, SceneError};
use glam::Affine3A;
use std::path::Path;
use std::sync::Arc;

/// One input file by name, with its bytes.
#[derive(Debug, Clone)]
pub struct NamedBytes {
    pub name: String,
    pub data: Vec<u8>,
}

fn extension(name: &str) -> String {
    Path::new(name).extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase()
}

fn stem(name: &str) -> String {
    Path::new(name).file_stem().and_then(|e| e.to_str()).unwrap_or("scene").to_string()
}

/// Loads a scene from files: the first is the main file (.ply, .obj, .xml, .gltf, .glb,
/// any of them .gz, or a built-in description); the rest are files it references (an OBJ's
/// .mtl, a Mitsuba scene's meshes and textures, a glTF's buffers and images). Errors name
/// the file and the line, element or JSON path.
pub fn load_files(files: &[NamedBytes], progress: &dyn Progress) -> Result<Scene, SceneError> {
    let first = files.first().ok_or_else(|| SceneError::file("<none>", "no scene file given"))?;
    if first.data.is_empty() {
        return Err(SceneError::file(&first.name, "file is empty"));
    }
    let main = files::ungzip(first)?;
    let main = main.as_ref();
    let name = main.name.as_str();
    match extension(name).as_str() {
        crate::builtin::DESCRIPTION_EXTENSION => {
            // A built-in made from data files: the description names it, the rest are its data.
            let builtin = crate::builtin::parse_description(main)?;
            crate::builtin::load_with_files(&builtin, &files[1..], progress)
        }
        "ply" => {
            let mesh = mesh_from_file(main, progress)?;
            let obj = Object {
                name: stem(name),
                mesh: Arc::new(mesh),
                material: Material::diffuse("model", glam::Vec3::splat(0.73)),
                transform: Affine3A::IDENTITY,
            };
            Ok(stage_meshes(&stem(name), vec![obj], Vec::new(), None))
        }
        "obj" => {
            let data = obj::read(main, files, progress)?;
            let mut scratch = Vec::new();
            let mut objects = Vec::new();
            let mut lights = Vec::new();
            for run in &data.runs {
                if run.material.emission.max_element() > 0.0 {
                    for p in &run.polygons {
                        let l = Light::Area {
                            vertices: p.iter().map(|&i| data.positions[i as usize]).collect(),
                            radiance: run.material.emission,
                        };
                        match l.validate() {
                            Ok(()) => lights.push(l),
                            Err(e) => tracing::warn!("{name}: emissive face of {} is not a usable area light: {e}", run.name),
                        }
                    }
                }
                let corners = data.corners(run);
                let mesh = run_mesh(&data.positions, run.triangles.clone(), corners, &mut scratch, progress);
                if mesh.triangles.is_empty() {
                    continue;
                }
                objects.push(Object { name: run.name.clone(), mesh: Arc::new(mesh), material: run.material.clone(), transform: Affine3A::IDENTITY });
            }
            if objects.is_empty() {
                return Err(SceneError::file(name, "OBJ file has no (non-degenerate) faces"));
            }
            Ok(stage_meshes(&stem(name), objects, lights, None))
        }
        "xml" => mitsuba::load(main, files, progress),
        "gltf" | "glb" => gltf::load(main, files, progress),
        other => Err(SceneError::file(
            name,
            format!("unsupported scene file type `.{other}` (supported: .ply, .obj, .xml (Mitsuba 3), .gltf, .glb, each also .gz; .builtin)"),
        )),
    }
}

/// What a scene file says about the view, read without loading its meshes (the viewer
/// sizes its frames and picks a named camera with it).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FileView {
    /// The file's camera: the one called `camera_name`, else its first.
    pub camera: Option<Camera>,
    /// The film (image) size the file asks for.
    pub film: Option<(u32, u32)>,
}

/// The camera and film size of a scene file (Mitsuba XML, glTF; other formats have
/// neither). `camera_name` picks a camera by name (glTF camera or node name, Mitsuba sensor
/// id); a name the file does not have is an error listing the ones it has.
pub fn file_view(files: &[NamedBytes], camera_name: Option<&str>) -> Result<FileView, SceneError> {
    let Some(first) = files.first() else { return Ok(FileView::default()) };
    let main = files::ungzip(first)?;
    match extension(&main.name).as_str() {
        "xml" => mitsuba::view(&main, camera_name),
        "gltf" | "glb" => gltf::view(&main, files, camera_name),
        _ => match camera_name {
            Some(n) => Err(SceneError::file(&main.name, format!("--camera-name {n}: this file type has no cameras"))),
            None => Ok(FileView::default()),
        },
    }
}

/// The mesh of one OBJ run: only the vertices its triangles use (in their file order, so
/// welding picks the same representatives as on the whole list), welded. Welding the whole
/// vertex list for every object made a file of many small objects quadratic. `scratch` maps
/// file vertices to run vertices; it is left all `u32::MAX` for the next run.
fn run_mesh(
    positions: &[glam::Vec3],
    mut triangles: Vec<[u32; 3]>,
    corners: crate::Corners,
    scratch: &mut Vec<u32>,
    progress: &dyn Progress,
) -> Mesh {
    let mut used: Vec<u32> = triangles.iter().flatten().copied().collect();
    used.sort_unstable();
    used.dedup();
    if scratch.len() < positions.len() {
        scratch.resize(positions.len(), u32::MAX);
    }
    let local: Vec<glam::Vec3> = used.iter().map(|&i| positions[i as usize]).collect();
    for (k, &i) in used.iter().enumerate() {
        scratch[i as usize] = k as u32;
    }
    for t in &mut triangles {
        *t = t.map(|i| scratch[i as usize]);
    }
    for &i in &used {
        scratch[i as usize] = u32::MAX;
    }
    Mesh::from_triangles_with_corners(local, triangles, corners, progress)
}

/// The welded mesh of a mesh file (.ply; .obj: all its faces as one mesh, with its `vn` /
/// `vt` corner attributes; either also .gz).
pub(crate) fn mesh_from_file(file: &NamedBytes, progress: &dyn Progress) -> Result<Mesh, SceneError> {
    let file = files::ungzip(file)?;
    let name = file.name.as_str();
    let mesh = match extension(name).as_str() {
        "ply" => {
            let (positions, triangles) = ply::read(name, &file.data, progress)?;
            Mesh::from_triangles(positions, triangles, progress)
        }
        "obj" => {
            let data = obj::read(&file, &[], progress)?;
            let mut corners = crate::Corners::default();
            let mut normals = Vec::new();
            let mut uvs = Vec::new();
            for r in &data.runs {
                let c = data.corners(r);
                corners.normals = corners.normals.or(c.normals.as_ref().map(|_| Vec::new()));
                corners.uvs = corners.uvs.or(c.uvs.as_ref().map(|_| Vec::new()));
                normals.push((r.triangles.len(), c.normals));
                uvs.push((r.triangles.len(), c.uvs));
            }
            // Runs without an attribute another run has get zeros, keeping the alignment.
            fn join<T: Copy + Default>(parts: Vec<(usize, Option<Vec<[T; 3]>>)>) -> Vec<[T; 3]> {
                parts.into_iter().flat_map(|(n, p)| p.unwrap_or_else(|| vec![[T::default(); 3]; n])).collect()
            }
            if corners.normals.is_some() {
                corners.normals = Some(join(normals));
            }
            if corners.uvs.is_some() {
                corners.uvs = Some(join(uvs));
            }
            let triangles = data.runs.into_iter().flat_map(|r| r.triangles).collect();
            Mesh::from_triangles_with_corners(data.positions, triangles, corners, progress)
        }
        other => return Err(SceneError::file(name, format!("unsupported mesh file type `.{other}` (supported: .ply, .obj, each also .gz)"))),
    };
    if mesh.triangles.is_empty() {
        return Err(SceneError::file(name, "mesh has no (non-degenerate) triangles"));
    }
    Ok(mesh)
}

/// Reads a scene file from disk with the files it references ([`gather`]: an OBJ's
/// `mtllib`s, a Mitsuba scene's meshes, a glTF's buffers and images, each under
/// [`reference_path`]'s rules; one it may not read, or that is missing, is a warning, as
/// in the loader) and loads it.
pub fn load_path(path: &Path, progress: &dyn Progress) -> Result<Scene, SceneError> {
    load_files(&gather(path)?, progress)
}
