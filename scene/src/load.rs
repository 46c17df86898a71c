//! Scene files: PLY (binary and ASCII) and OBJ (+MTL colours). A file that brings no lights
//! or camera (every PLY, most OBJs) is staged by [`stage_meshes`]: the model on a floor under
//! a point light, framed by the camera.
mod obj;
mod ply;
mod stage;

pub use obj::{mtllib_names, mtllib_path};
pub use stage::stage_meshes;

use crate::{Light, Material, Mesh, Object, Progress, Scene, SceneError};
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

/// Loads a scene from files: the first is the main file (.ply or .obj); the rest are files
/// it references (an OBJ's .mtl). Errors name the file and the line or element.
pub fn load_files(files: &[NamedBytes], progress: &dyn Progress) -> Result<Scene, SceneError> {
    let main = files.first().ok_or_else(|| SceneError::file("<none>", "no scene file given"))?;
    let name = main.name.as_str();
    if main.data.is_empty() {
        return Err(SceneError::file(name, "file is empty"));
    }
    match extension(name).as_str() {
        crate::builtin::DESCRIPTION_EXTENSION => {
            // A built-in made from data files: the description names it, the rest are its data.
            let builtin = crate::builtin::parse_description(main)?;
            crate::builtin::load_with_files(&builtin, &files[1..], progress)
        }
        "ply" => {
            let (positions, triangles) = ply::read(name, &main.data, progress)?;
            let mesh = Mesh::from_triangles(positions, triangles, progress);
            if mesh.triangles.is_empty() {
                return Err(SceneError::file(name, "mesh has no (non-degenerate) triangles"));
            }
            let obj = Object {
                name: stem(name),
                mesh: Arc::new(mesh),
                material: Material::diffuse("model", glam::Vec3::splat(0.73)),
                transform: Affine3A::IDENTITY,
            };
            Ok(stage_meshes(&stem(name), vec![obj], Vec::new()))
        }
        "obj" => {
            let data = obj::read(main, &files[1..], progress)?;
            let mut scratch = Vec::new();
            let mut objects = Vec::new();
            let mut lights = Vec::new();
            for run in data.runs {
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
                let mesh = run_mesh(&data.positions, run.triangles, &mut scratch, progress);
                if mesh.triangles.is_empty() {
                    continue;
                }
                objects.push(Object { name: run.name, mesh: Arc::new(mesh), material: run.material, transform: Affine3A::IDENTITY });
            }
            if objects.is_empty() {
                return Err(SceneError::file(name, "OBJ file has no (non-degenerate) faces"));
            }
            Ok(stage_meshes(&stem(name), objects, lights))
        }
        other => Err(SceneError::file(
            name,
            format!("unsupported scene file type `.{other}` (supported: .ply, .obj, .builtin)"),
        )),
    }
}

/// The mesh of one OBJ run: only the vertices its triangles use (in their file order, so
/// welding picks the same representatives as on the whole list), welded. Welding the whole
/// vertex list for every object made a file of many small objects quadratic. `scratch` maps
/// file vertices to run vertices; it is left all `u32::MAX` for the next run.
fn run_mesh(positions: &[glam::Vec3], mut triangles: Vec<[u32; 3]>, scratch: &mut Vec<u32>, progress: &dyn Progress) -> Mesh {
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
    Mesh::from_triangles(local, triangles, progress)
}

/// The welded mesh of a mesh file (.ply; .obj: all its faces as one mesh).
pub(crate) fn mesh_from_file(file: &NamedBytes, progress: &dyn Progress) -> Result<Mesh, SceneError> {
    let name = file.name.as_str();
    let mesh = match extension(name).as_str() {
        "ply" => {
            let (positions, triangles) = ply::read(name, &file.data, progress)?;
            Mesh::from_triangles(positions, triangles, progress)
        }
        "obj" => {
            let data = obj::read(file, &[], progress)?;
            let triangles = data.runs.into_iter().flat_map(|r| r.triangles).collect();
            Mesh::from_triangles(data.positions, triangles, progress)
        }
        other => return Err(SceneError::file(name, format!("unsupported mesh file type `.{other}` (supported: .ply, .obj)"))),
    };
    if mesh.triangles.is_empty() {
        return Err(SceneError::file(name, "mesh has no (non-degenerate) triangles"));
    }
    Ok(mesh)
}

/// Reads a scene file from disk (for an OBJ also the `mtllib` files it may name: see
/// [`mtllib_path`]; one it may not, or that is missing, is a warning, as in the loader) and
/// loads it.
pub fn load_path(path: &Path, progress: &dyn Progress) -> Result<Scene, SceneError> {
    let shown = path.display().to_string();
    let data = std::fs::read(path).map_err(|e| SceneError::file(&shown, format!("cannot read: {e}")))?;
    let mut files = vec![NamedBytes { name: shown.clone(), data }];
    if extension(&shown) == "obj" {
        let dir = path.parent().unwrap_or(Path::new("."));
        for (line, lib) in mtllib_names(&files[0].data) {
            match mtllib_path(dir, &lib).and_then(|p| std::fs::read(&p).map_err(|e| format!("cannot read {}: {e}", p.display()))) {
                Ok(d) => files.push(NamedBytes { name: lib, data: d }),
                Err(e) => tracing::warn!("{shown}:{line}: mtllib {lib}: {e}; its materials fall back to the default"),
            }
        }
    }
    load_files(&files, progress)
}
