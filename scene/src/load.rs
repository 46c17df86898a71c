//! Scene files: PLY (binary and ASCII) and OBJ (+MTL colours).
use crate::{Progress, Scene, SceneError};

/// One input file by name, with its bytes.
#[derive(Debug, Clone)]
pub struct NamedBytes {
    pub name: String,
    pub data: Vec<u8>,
}

/// Loads a scene from files: the first is the main file (.ply or .obj); the rest are files
/// it references (an OBJ's .mtl).
pub fn load_files(files: &[NamedBytes], _progress: &dyn Progress) -> Result<Scene, SceneError> {
    let main = files.first().ok_or_else(|| SceneError::file("<none>", "no scene file given"))?;
    Err(SceneError::file(&main.name, "loader in progress"))
}
