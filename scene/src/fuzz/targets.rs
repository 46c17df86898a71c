//! The parsers under fuzzing, one line each in [`TARGETS`]. A target turns one input into
//! what a server or worker would build from it: the scene files loaded, staged and
//! validated. A new scene format (glTF, Mitsuba XML) adds its line here and a seed
//! directory `fuzz/seeds/<name>/`; the harness, the test and `edgepoint-bench fuzz` need no
//! other change.
use crate::load::{load_files, NamedBytes};
use crate::NoProgress;

/// A parser under fuzzing.
#[derive(Clone, Copy)]
pub struct Target {
    /// Name of the target, of its seed and crash directories, and of `--parser`.
    pub name: &'static str,
    /// Extension of its corpus files.
    pub ext: &'static str,
    /// What it checks, for `--help` and reports.
    pub about: &'static str,
    /// Parses one input. `Err` is a fine outcome (a clear refusal); only a panic, a slow
    /// parse or an out-of-proportion allocation is a finding.
    pub run: fn(&[u8]) -> Result<(), String>,
}

impl std::fmt::Debug for Target {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name)
    }
}

/// Every fuzzed parser.
pub const TARGETS: &[Target] = &[
    Target { name: "ply", ext: "ply", about: "PLY reader (ASCII and binary), weld, staging", run: ply },
    Target { name: "obj", ext: "obj", about: "OBJ reader with a fixed MTL, objects, weld, staging", run: obj },
    Target { name: "mtl", ext: "mtl", about: "MTL reader, used by a fixed OBJ", run: mtl },
    Target { name: "grid-dragon", ext: "ply", about: "the grid-dragon built-in around a fuzzed dragon PLY", run: grid_dragon },
    Target { name: "mitsuba", ext: "xml", about: "Mitsuba 3 XML with a fixed OBJ mesh file, spectra, transforms, staging", run: mitsuba },
    Target { name: "gltf", ext: "gltf", about: "glTF JSON with a fixed external buffer (and data-URI buffers)", run: gltf },
    Target { name: "glb", ext: "glb", about: "binary glTF (JSON and BIN chunks)", run: glb },
    Target { name: "gz", ext: "gz", about: "gzip layer (bounded inflation) around an OBJ", run: gz },
];

/// The target called `name`.
pub fn target(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

fn load(files: &[NamedBytes]) -> Result<(), String> {
    let scene = load_files(files, &NoProgress).map_err(|e| e.to_string())?;
    scene.validate()
}

fn file(name: &str, data: &[u8]) -> NamedBytes {
    NamedBytes { name: name.to_string(), data: data.to_vec() }
}

fn ply(input: &[u8]) -> Result<(), String> {
    load(&[file("fuzz.ply", input)])
}

/// The MTL the `obj` target's inputs may name with `mtllib fuzz.mtl`.
const OBJ_MTL: &[u8] = b"newmtl white\nKd 0.8 0.8 0.8\nnewmtl lamp\nKd 0.5 0.5 0.5\nKe 10 10 10\n";

fn obj(input: &[u8]) -> Result<(), String> {
    load(&[file("fuzz.obj", input), file("fuzz.mtl", OBJ_MTL)])
}

/// The OBJ that uses the `mtl` target's inputs: a box and a lamp quad.
const MTL_OBJ: &[u8] = b"mtllib fuzz.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 2 0\nv 1 2 0\nv 1 2 1\nv 0 2 1\no box\nusemtl white\nf 1 2 3 4\no lamp\nusemtl lamp\nf 5 6 7 8\nusemtl red\nf 1 3 2\n";

fn mtl(input: &[u8]) -> Result<(), String> {
    load(&[file("fuzz.obj", MTL_OBJ), file("fuzz.mtl", input)])
}

fn grid_dragon(input: &[u8]) -> Result<(), String> {
    load(&[crate::builtin::description("grid-dragon"), file(crate::builtin::data_files("grid-dragon")[0], input)])
}

/// The mesh file the `mitsuba` target's inputs may name (`meshes/quad.obj`).
const MITSUBA_OBJ: &[u8] = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1 4//1\n";

fn mitsuba(input: &[u8]) -> Result<(), String> {
    load(&[file("fuzz.xml", input), file("meshes/quad.obj", MITSUBA_OBJ)])
}

/// The external buffer the `gltf` target's inputs may name (`quad.bin`): a unit quad's
/// positions (48 bytes), normals (48), UVs (32) and u16 indices (12 + 4 padding).
fn gltf_quad_buffer() -> Vec<u8> {
    let mut b = Vec::new();
    let f = |b: &mut Vec<u8>, v: &[f32]| v.iter().for_each(|x| b.extend(x.to_le_bytes()));
    f(&mut b, &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0]);
    f(&mut b, &[0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
    f(&mut b, &[0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]);
    [0u16, 1, 2, 0, 2, 3].iter().for_each(|i| b.extend(i.to_le_bytes()));
    b.extend([0; 4]);
    b
}

fn gltf(input: &[u8]) -> Result<(), String> {
    load(&[file("fuzz.gltf", input), file("quad.bin", &gltf_quad_buffer())])
}

fn glb(input: &[u8]) -> Result<(), String> {
    load(&[file("fuzz.glb", input)])
}

fn gz(input: &[u8]) -> Result<(), String> {
    load(&[file("fuzz.obj.gz", input)])
}
