//! Built-in scenes: the Cornell box, and scenes after paper 000's (§7.1, Figures 7, 9, 12,
//! 13): `chains`, `torus-capsule`, `grid-dragon`, `rooms`, `mackintosh`; `materials`, the demo
//! of the scattering models; `glossy-bunny`, the `glossy` shader's scene; and `cornell-glass`
//! (paper 004 Fig. 10), the `hybrid` shader's.
//!
//! Most are procedural. `grid-dragon` (and `glossy-bunny`) is built around the shared Stanford dragon, which is
//! data, not code: such a built-in names its data files ([`data_files`]) and is built by
//! [`load_with_files`] from their bytes. On the wire it travels as a `SceneFiles` source
//! whose first file is a small description (`grid-dragon.builtin`, see [`description`])
//! followed by the data files, so shader workers on other machines need no data directory
//! and cache it by content hash like any file scene. Clients find the data with
//! [`crate::data`].
mod chains;
mod cornell;
mod cornell_glass;
mod glossy_bunny;
mod grid_dragon;
mod mackintosh;
mod materials;
mod rooms;
pub mod shapes;
mod torus_capsule;

use crate::load::NamedBytes;
use crate::{Material, Mesh, Object, Progress, Scene, SceneError};
use glam::Affine3A;
use std::sync::Arc;

/// Names of the built-in scenes, with one line each.
pub const BUILTINS: &[(&str, &str)] = &[
    ("cornell", "Cornell box with a tall and a short box under the square ceiling area light"),
    ("cornell-point", "the Cornell box lit by a point light under the ceiling centre"),
    ("cornell-glass", "the Cornell box with a glass sphere and a mirror on the short box (paper 004 Fig. 10): for the hybrid shader"),
    ("chains", "32 tessellated linked tori in four chains on a floor, two point lights (paper Fig. 7)"),
    ("torus-capsule", "a torus resting on a capsule under a square area light: contact hardening (paper Fig. 9)"),
    ("grid-dragon", "a grid casting a shadow pattern on the Stanford dragon, point light (paper Fig. 13; needs dragon/dragon_vrip.ply)"),
    ("rooms", "six furnished rooms with doorways, one ceiling area light each (paper Fig. 12)"),
    ("glossy-bunny", "the Stanford bunny in rough gold on polished plastic before a mirror, area and point light: for the glossy shader (needs bunny/bun_zipper.ply)"),
    ("mackintosh", "a white room after Mackintosh: latticed window with daylight, high-back chairs, tea-stand, lattice screen, hanging lamp; three lights, fine geometry, for the gi shader (paper Fig. 10-11)"),
    ("materials", "a sphere of each material (Lambert, plastic, metal, glass; smooth and rough) under an area and a point light"),
];

/// Data files (paths under the shared data directory) a built-in is made from.
pub fn data_files(name: &str) -> &'static [&'static str] {
    match name {
        "grid-dragon" => &[grid_dragon::DRAGON],
        "glossy-bunny" => &[glossy_bunny::BUNNY],
        _ => &[],
    }
}

fn unknown(name: &str) -> String {
    format!("unknown built-in scene '{name}' (built-ins: {})", BUILTINS.iter().map(|b| b.0).collect::<Vec<_>>().join(", "))
}

/// Builds a built-in scene that needs no data files by name.
pub fn load(name: &str) -> Result<Scene, String> {
    match name {
        "cornell" => Ok(cornell::cornell(false)),
        "cornell-point" => Ok(cornell::cornell(true)),
        "cornell-glass" => Ok(cornell_glass::cornell_glass()),
        "chains" => Ok(chains::chains()),
        "torus-capsule" => Ok(torus_capsule::torus_capsule()),
        "rooms" => Ok(rooms::rooms()),
        "materials" => Ok(materials::materials()),
        "mackintosh" => Ok(mackintosh::mackintosh()),
        _ if BUILTINS.iter().any(|b| b.0 == name) => Err(format!(
            "built-in scene '{name}' is made from the data file(s) {} and must be loaded with them: \
             the viewer and the bench find them in the shared data directory (--data-dir, the {} \
             environment variable, or a shared/data directory above the working directory or the \
             executable) and send them along",
            data_files(name).join(", "),
            crate::data::DATA_ENV
        )),
        _ => Err(unknown(name)),
    }
}

/// Builds built-in `name` from its data files (named by their data paths, as in
/// [`data_files`]; any leading directories of the given names may differ).
pub fn load_with_files(name: &str, files: &[NamedBytes], progress: &dyn Progress) -> Result<Scene, SceneError> {
    let need = data_files(name);
    if need.is_empty() {
        return load(name).map_err(|e| SceneError::file(name, e));
    }
    let find = |path: &str| -> Result<&NamedBytes, SceneError> {
        let base = path.rsplit('/').next().unwrap_or(path);
        files.iter().find(|f| f.name == path || f.name.rsplit('/').next() == Some(base)).ok_or_else(|| {
            SceneError::file(format!("{name}.builtin"), format!("built-in '{name}' needs data file {path}, which was not sent"))
        })
    };
    match name {
        "grid-dragon" => {
            let dragon = crate::load::mesh_from_file(find(grid_dragon::DRAGON)?, progress)?;
            Ok(grid_dragon::grid_dragon(dragon))
        }
        "glossy-bunny" => {
            let bunny = crate::load::mesh_from_file(find(glossy_bunny::BUNNY)?, progress)?;
            Ok(glossy_bunny::glossy_bunny(bunny))
        }
        _ => Err(SceneError::file(name, unknown(name))),
    }
}

/// File extension of a built-in's description file.
pub const DESCRIPTION_EXTENSION: &str = "builtin";
const DESCRIPTION_HEADER: &str = "edgepoint-builtin 1";

/// The small description file that stands first in a built-in's `SceneFiles`.
pub fn description(name: &str) -> NamedBytes {
    let mut text = format!("{DESCRIPTION_HEADER}\nscene {name}\n");
    for d in data_files(name) {
        text.push_str(&format!("data {d}\n"));
    }
    NamedBytes { name: format!("{name}.{DESCRIPTION_EXTENSION}"), data: text.into_bytes() }
}

/// The built-in a description file names. Errors name the file and line.
pub fn parse_description(file: &NamedBytes) -> Result<String, SceneError> {
    let text = std::str::from_utf8(&file.data).map_err(|_| SceneError::file(&file.name, "description is not UTF-8 text"))?;
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, l)) if l.trim() == DESCRIPTION_HEADER => {}
        _ => return Err(SceneError::file(&file.name, format!("line 1: expected '{DESCRIPTION_HEADER}'"))),
    }
    let mut name = None;
    for (i, l) in lines {
        let mut w = l.split_whitespace();
        match (w.next(), w.next(), w.next()) {
            (None, _, _) => {}
            (Some("scene"), Some(n), None) => name = Some(n.to_string()),
            (Some("data"), Some(_), None) => {}
            _ => return Err(SceneError::file(&file.name, format!("line {}: expected 'scene NAME' or 'data PATH', got '{l}'", i + 1))),
        }
    }
    let name = name.ok_or_else(|| SceneError::file(&file.name, "no 'scene NAME' line"))?;
    if !BUILTINS.iter().any(|b| b.0 == name) {
        return Err(SceneError::file(&file.name, unknown(&name)));
    }
    Ok(name)
}

pub(crate) fn object(name: &str, mesh: Mesh, material: Material) -> Object {
    Object { name: name.to_string(), mesh: Arc::new(mesh), material, transform: Affine3A::IDENTITY }
}

pub(crate) fn object_at(name: &str, mesh: Mesh, material: Material, transform: Affine3A) -> Object {
    Object { name: name.to_string(), mesh: Arc::new(mesh), material, transform }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn procedural_builtins_are_valid() {
        for (name, _) in BUILTINS {
            if !data_files(name).is_empty() {
                let e = load(name).unwrap_err();
                assert!(e.contains("data file") && e.contains(crate::data::DATA_ENV), "{e}");
                continue;
            }
            let s = load(name).unwrap();
            s.validate().unwrap();
            assert_eq!(s.name, *name);
        }
        assert!(load("nope").unwrap_err().contains("cornell"));
    }

    #[test]
    fn descriptions_round_trip_and_bad_ones_name_the_line() {
        let d = description("grid-dragon");
        assert_eq!(d.name, "grid-dragon.builtin");
        assert_eq!(parse_description(&d).unwrap(), "grid-dragon");
        let bad = NamedBytes { name: "x.builtin".into(), data: b"edgepoint-builtin 1\nscene\n".to_vec() };
        let e = parse_description(&bad).unwrap_err().to_string();
        assert!(e.contains("x.builtin") && e.contains("line 2"), "{e}");
        let bad = NamedBytes { name: "y.builtin".into(), data: b"hello\n".to_vec() };
        assert!(parse_description(&bad).unwrap_err().to_string().contains("line 1"));
        let unknown = NamedBytes { name: "z.builtin".into(), data: b"edgepoint-builtin 1\nscene nope\n".to_vec() };
        assert!(parse_description(&unknown).unwrap_err().to_string().contains("unknown built-in"));
        // Without its data, grid-dragon says which file is missing.
        let e = load_with_files("grid-dragon", &[], &crate::NoProgress).unwrap_err().to_string();
        assert!(e.contains("dragon_vrip.ply"), "{e}");
    }
}
