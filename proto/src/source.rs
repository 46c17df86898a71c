//! Building a [`Scene`] from a wire [`SceneSource`] — the one place server and workers turn
//! a source into a scene, so both always hold the same scene for the same hash.
use crate::v1::{self, scene_source::Source};
use edgepoint_scene::load::{self, NamedBytes};
use edgepoint_scene::{builtin, Progress, Scene, SceneError};

/// A source naming a built-in scene.
pub fn builtin_source(name: &str) -> v1::SceneSource {
    v1::SceneSource { source: Some(Source::Builtin(name.to_string())) }
}

/// A source carrying files (the first is the main one).
pub fn files_source(files: Vec<(String, Vec<u8>)>) -> v1::SceneSource {
    v1::SceneSource {
        source: Some(Source::Files(v1::SceneFiles {
            files: files.into_iter().map(|(name, data)| v1::NamedFile { name, data }).collect(),
        })),
    }
}

/// Short human description of a source ("builtin cornell", "file bunny.ply").
pub fn describe_source(src: &v1::SceneSource) -> String {
    match &src.source {
        Some(Source::Builtin(n)) => format!("builtin {n}"),
        Some(Source::Files(f)) => match f.files.first() {
            Some(file) => format!("file {} ({} bytes)", file.name, file.data.len()),
            None => "no files".into(),
        },
        None => "empty source".into(),
    }
}

/// Builds and validates the scene a source describes. Errors name the file and place.
pub fn scene_from_source(src: &v1::SceneSource, progress: &dyn Progress) -> Result<Scene, SceneError> {
    let scene = match &src.source {
        Some(Source::Builtin(name)) => builtin::load(name).map_err(|e| SceneError::file(name.as_str(), e))?,
        Some(Source::Files(f)) => {
            let files: Vec<NamedBytes> =
                f.files.iter().map(|nf| NamedBytes { name: nf.name.clone(), data: nf.data.clone() }).collect();
            load::load_files(&files, progress)?
        }
        None => return Err(SceneError::file("<scene>", "scene source is empty: name a built-in or send files")),
    };
    let name = match &src.source {
        Some(Source::Files(f)) => f.files.first().map(|x| x.name.clone()).unwrap_or_default(),
        _ => scene.name.clone(),
    };
    scene.validate().map_err(|e| SceneError::file(name, e))?;
    Ok(scene)
}
