//! Scene files: PLY (binary and ASCII) and OBJ (+MTL colours). A file that brings no lights
//! or camera (every PLY, most OBJs) is staged by [`stage_meshes`]: the model on a floor under
//! a point light, framed by the camera.
mod obj;
mod ply;
mod stage;

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
                let mesh = Mesh::from_triangles(data.positions.clone(), run.triangles, progress);
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

/// Reads a scene file from disk (for an OBJ also the `mtllib` files next to it) and loads it.
pub fn load_path(path: &Path, progress: &dyn Progress) -> Result<Scene, SceneError> {
    let shown = path.display().to_string();
    let data = std::fs::read(path).map_err(|e| SceneError::file(&shown, format!("cannot read: {e}")))?;
    let mut files = vec![NamedBytes { name: shown.clone(), data }];
    if extension(&shown) == "obj" {
        let text = String::from_utf8_lossy(&files[0].data).into_owned();
        for line in text.lines() {
            let mut w = line.split_whitespace();
            if w.next() == Some("mtllib") {
                for lib in w {
                    let p = path.parent().unwrap_or(Path::new(".")).join(lib);
                    if let Ok(d) = std::fs::read(&p) {
                        files.push(NamedBytes { name: p.display().to_string(), data: d });
                    }
                }
            }
        }
    }
    load_files(&files, progress)
}
