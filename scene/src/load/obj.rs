//! Wavefront OBJ reader (+ MTL colours). `v`, `vn`, `vt` and `f` (forms `v`, `v/vt`,
//! `v//vn`, `v/vt/vn`, negative = relative indices; polygons fan-triangulated); `o` / `g`
//! start a new object and `usemtl` a new material run: each (object, material) run becomes
//! one scene object. Normals and texture coordinates become per-corner attributes
//! ([`crate::Corners`]) of the triangles. `mtllib` files are looked up among the given files
//! ([`super::files::find`]; a library that was not given is a warning and its materials
//! fall back to the default, as in the viewer, which sends only the libraries it may: see
//! [`super::files::reference_path`]); a `usemtl` naming no material of the libraries is a
//! warning too. MTL `Kd` is the diffuse colour and `Ke` the emission. Other statements are
//! ignored.
//!
//! Cost is linear in the file: runs are found by a map, not by a search over the runs so
//! far, and only emissive runs keep their source polygons (for their area lights).
use crate::error::SceneError;
use crate::limits::{check_coordinate, MAX_COORDINATE};
use crate::load::NamedBytes;
use crate::{Material, Progress};
use glam::Vec3;
use glam::Vec2;
use std::collections::HashMap;

/// One (object, material) run of faces, indices into the file's global vertex list.
pub struct Run {
    pub name: String,
    pub material: Material,
    pub triangles: Vec<[u32; 3]>,
    /// Per triangle, the `vn` index of each corner ([`NONE`] where the face gave none).
    pub normal_ids: Vec<[u32; 3]>,
    /// Per triangle, the `vt` index of each corner ([`NONE`] where the face gave none).
    pub uv_ids: Vec<[u32; 3]>,
    /// Source polygons of an emissive run (its faces become area lights); empty otherwise.
    pub polygons: Vec<Vec<u32>>,
}

/// No `vn` / `vt` for this corner.
pub const NONE: u32 = u32::MAX;

pub struct ObjData {
    pub positions: Vec<Vec3>,
    /// `vn` normals (normalized; zero where the file gave a zero vector).
    pub normals: Vec<Vec3>,
    /// `vt` coordinates (u, v).
    pub uvs: Vec<Vec2>,
    pub runs: Vec<Run>,
}

impl ObjData {
    /// The corner attributes of `run`'s triangles: present when any corner of the run has
    /// them (corners without get a zero normal / zero UV).
    pub fn corners(&self, run: &Run) -> crate::Corners {
        let normals = run.normal_ids.iter().any(|t| t.iter().any(|&i| i != NONE)).then(|| {
            run.normal_ids.iter().map(|t| t.map(|i| if i == NONE { Vec3::ZERO } else { self.normals[i as usize] })).collect()
        });
        let uvs = run.uv_ids.iter().any(|t| t.iter().any(|&i| i != NONE)).then(|| {
            run.uv_ids.iter().map(|t| t.map(|i| if i == NONE { Vec2::ZERO } else { self.uvs[i as usize] })).collect()
        });
        crate::Corners { normals, uvs }
    }
}

/// The 0-based index an OBJ index `tok` (1-based, or negative = relative) names among `n`
/// defined so far.
fn obj_index(name: &str, ln: usize, tok: &str, n: usize, what: &str, plural: &str) -> Result<u32, SceneError> {
    let idx: i64 = tok.parse().map_err(|_| SceneError::line(name, ln, format!("{what} index `{tok}` is not a whole number")))?;
    let n = n as i64;
    let abs = if idx > 0 { idx - 1 } else { n + idx };
    if idx == 0 || abs < 0 || abs >= n {
        return Err(SceneError::line(name, ln, format!("face refers to {what} {idx} but {n} {plural} are defined so far")));
    }
    Ok(abs as u32)
}

fn parse_f32(name: &str, ln: usize, tok: Option<&str>, what: &str) -> Result<f32, SceneError> {
    let t = tok.ok_or_else(|| SceneError::line(name, ln, format!("missing {what}")))?;
    let v: f64 = t.parse().map_err(|_| SceneError::line(name, ln, format!("{what} `{t}` is not a number")))?;
    if !v.is_finite() {
        return Err(SceneError::line(name, ln, format!("{what} `{t}` is not finite")));
    }
    if !(v.abs() <= f32::MAX as f64) {
        return Err(SceneError::line(name, ln, format!("{what} `{t}` is too large")));
    }
    Ok(v as f32)
}

/// A vertex coordinate: a number within ±[`MAX_COORDINATE`].
fn parse_coordinate(name: &str, ln: usize, tok: Option<&str>, what: &str) -> Result<f32, SceneError> {
    let v = parse_f32(name, ln, tok, what)?;
    check_coordinate(v as f64, MAX_COORDINATE).map_err(|m| SceneError::line(name, ln, format!("{what}: {m}")))?;
    Ok(v)
}

/// `(line number, name)` for every name on every `mtllib` line of an OBJ file.
pub fn mtllib_names(data: &[u8]) -> Vec<(usize, String)> {
    let text = String::from_utf8_lossy(data);
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        let mut words = line.split_whitespace();
        if words.next() == Some("mtllib") {
            out.extend(words.map(|w| (i + 1, w.to_string())));
        }
    }
    out
}

/// Parses an MTL file into materials by name.
pub fn read_mtl(name: &str, data: &[u8]) -> Result<HashMap<String, Material>, SceneError> {
    let text = std::str::from_utf8(data).map_err(|_| SceneError::file(name, "MTL file is not UTF-8 text"))?;
    let mut out = HashMap::new();
    let mut cur: Option<Material> = None;
    for (i, line) in text.lines().enumerate() {
        let ln = i + 1;
        let mut w = line.split_whitespace();
        match w.next() {
            Some("newmtl") => {
                if let Some(m) = cur.take() {
                    out.insert(m.name.clone(), m);
                }
                let n = w.next().ok_or_else(|| SceneError::line(name, ln, "`newmtl` needs a name"))?;
                cur = Some(Material::diffuse(n, Vec3::splat(0.7)));
            }
            Some(k @ ("Kd" | "Ke")) => {
                let m = cur.as_mut().ok_or_else(|| SceneError::line(name, ln, format!("`{k}` before any `newmtl`")))?;
                let c = Vec3::new(
                    parse_f32(name, ln, w.next(), "red")?,
                    parse_f32(name, ln, w.next(), "green")?,
                    parse_f32(name, ln, w.next(), "blue")?,
                );
                if k == "Kd" {
                    m.diffuse = c.clamp(Vec3::ZERO, Vec3::ONE);
                } else {
                    m.emission = c.max(Vec3::ZERO);
                }
            }
            _ => {}
        }
    }
    if let Some(m) = cur.take() {
        out.insert(m.name.clone(), m);
    }
    Ok(out)
}

/// Parses an OBJ file; `files` are the scene's files (main first), where its MTL
/// libraries are looked up.
pub fn read(main: &NamedBytes, files: &[NamedBytes], progress: &dyn Progress) -> Result<ObjData, SceneError> {
    let name = main.name.as_str();
    let text = std::str::from_utf8(&main.data).map_err(|_| SceneError::file(name, "OBJ file is not UTF-8 text"))?;
    progress.begin(&format!("parse {name}"), text.len() as u64);
    let mut positions: Vec<Vec3> = Vec::new();
    let mut normals: Vec<Vec3> = Vec::new();
    let mut uvs: Vec<Vec2> = Vec::new();
    let mut libraries_given = false;
    let mut warned_missing: std::collections::HashSet<String> = Default::default();
    let mut materials: HashMap<String, Material> = HashMap::new();
    let mut runs: Vec<Run> = Vec::new();
    let mut obj_name = String::new();
    let mut mat = Material::default();
    // The run faces go to, and every run by (object, material).
    let mut open: Option<usize> = None;
    let mut run_of: HashMap<(String, String), usize> = HashMap::new();
    let mut poly: Vec<u32> = Vec::new();
    let mut poly_n: Vec<u32> = Vec::new();
    let mut poly_t: Vec<u32> = Vec::new();
    let mut done = 0u64;
    for (i, line) in text.lines().enumerate() {
        let ln = i + 1;
        done += line.len() as u64 + 1;
        if ln % 100_000 == 0 {
            progress.advance(done);
            done = 0;
        }
        let line = line.split('#').next().unwrap_or("");
        let mut w = line.split_whitespace();
        match w.next() {
            Some("v") => {
                let v = Vec3::new(
                    parse_coordinate(name, ln, w.next(), "x")?,
                    parse_coordinate(name, ln, w.next(), "y")?,
                    parse_coordinate(name, ln, w.next(), "z")?,
                );
                if positions.len() >= u32::MAX as usize - 1 {
                    return Err(SceneError::line(name, ln, "more vertices than a mesh can index (2^32 - 1)"));
                }
                positions.push(v);
            }
            Some("vn") => {
                let n = Vec3::new(
                    parse_f32(name, ln, w.next(), "normal x")?,
                    parse_f32(name, ln, w.next(), "normal y")?,
                    parse_f32(name, ln, w.next(), "normal z")?,
                );
                normals.push(n.normalize_or_zero());
            }
            Some("vt") => {
                let u = parse_f32(name, ln, w.next(), "texture u")?;
                // `vt u` alone is valid OBJ (v defaults to 0).
                let v = if w.clone().next().is_some() { parse_f32(name, ln, w.next(), "texture v")? } else { 0.0 };
                uvs.push(Vec2::new(u, v));
            }
            Some("f") => {
                poly.clear();
                poly_n.clear();
                poly_t.clear();
                for tok in w {
                    let mut parts = tok.split('/');
                    let first = parts.next().unwrap_or("");
                    if first.parse::<i64>().is_err() {
                        return Err(SceneError::line(name, ln, format!("face vertex `{tok}` does not start with a vertex index")));
                    }
                    poly.push(obj_index(name, ln, first, positions.len(), "vertex", "vertices")?);
                    let t = parts.next().filter(|t| !t.is_empty());
                    poly_t.push(match t {
                        Some(t) => obj_index(name, ln, t, uvs.len(), "texture coordinate", "texture coordinates")?,
                        None => NONE,
                    });
                    let n = parts.next().filter(|t| !t.is_empty());
                    poly_n.push(match n {
                        Some(n) => obj_index(name, ln, n, normals.len(), "normal", "normals")?,
                        None => NONE,
                    });
                }
                if poly.len() < 3 {
                    return Err(SceneError::line(name, ln, format!("face has {} vertices; at least 3 are needed", poly.len())));
                }
                if open.is_none() {
                    let n = if obj_name.is_empty() { "object".to_string() } else { obj_name.clone() };
                    // The same object and material again continue their earlier run.
                    let key = (n, mat.name.clone());
                    let k = match run_of.get(&key) {
                        Some(&k) => k,
                        None => {
                            runs.push(Run {
                                name: key.0.clone(),
                                material: mat.clone(),
                                triangles: Vec::new(),
                                normal_ids: Vec::new(),
                                uv_ids: Vec::new(),
                                polygons: Vec::new(),
                            });
                            run_of.insert(key, runs.len() - 1);
                            runs.len() - 1
                        }
                    };
                    open = Some(k);
                }
                let run = &mut runs[open.expect("a run is open")];
                for k in 1..poly.len() - 1 {
                    run.triangles.push([poly[0], poly[k], poly[k + 1]]);
                    run.normal_ids.push([poly_n[0], poly_n[k], poly_n[k + 1]]);
                    run.uv_ids.push([poly_t[0], poly_t[k], poly_t[k + 1]]);
                }
                if run.material.emission.max_element() > 0.0 {
                    run.polygons.push(poly.clone());
                }
            }
            Some("o") | Some("g") => {
                obj_name = w.collect::<Vec<_>>().join(" ");
                open = None;
            }
            Some("usemtl") => {
                let m = w.next().ok_or_else(|| SceneError::line(name, ln, "`usemtl` needs a material name"))?;
                mat = match materials.get(m) {
                    Some(found) => found.clone(),
                    None => {
                        if warned_missing.insert(m.to_string()) {
                            let why = if libraries_given { "no material library given defines it" } else { "no material library was given" };
                            tracing::warn!("{name}:{ln}: usemtl {m}: {why}; its faces get the default grey");
                        }
                        Material { name: m.to_string(), ..Material::default() }
                    }
                };
                open = None;
            }
            Some("mtllib") => {
                for lib in w {
                    match super::files::find(files, lib) {
                        Some(f) => {
                            libraries_given = true;
                            let f = super::files::ungzip(f)?;
                            materials.extend(read_mtl(&f.name, &f.data)?)
                        }
                        None => tracing::warn!("{name}:{ln}: material library {lib} was not given; using default materials"),
                    }
                }
            }
            _ => {}
        }
    }
    progress.advance(done);
    progress.end();
    // Runs of the same object with several materials get the material in their name.
    let mut counts: HashMap<String, usize> = HashMap::new();
    for r in &runs {
        *counts.entry(r.name.clone()).or_default() += 1;
    }
    for r in &mut runs {
        if counts[&r.name] > 1 {
            r.name = format!("{}:{}", r.name, r.material.name);
        }
    }
    Ok(ObjData { positions, normals, uvs, runs })
}
