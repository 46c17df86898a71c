//! The files a scene is made of. A scene travels as bytes (`SceneFiles`: the main file
//! first, then every file it references), parsed alike by the server and the workers, so
//! one mechanism serves every format: [`references`] lists what a main file names (an OBJ's
//! `mtllib`, a Mitsuba XML's mesh `filename`s, a glTF's buffer and image URIs), [`gather`]
//! reads those from disk under the rules of [`reference_path`], and the loaders find them in
//! the list with [`find`]. `.gz` files are inflated here, bounded ([`inflate`]).
use super::{extension, NamedBytes};
use crate::SceneError;
use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// Largest inflated size of a `.gz` file, whatever its trailer claims.
pub const MAX_INFLATED_BYTES: u64 = 2 << 30;
/// Largest inflation ratio accepted (a real OBJ or PLY compresses 2–10×; a gzip bomb
/// reaches 1000×). Past it the file is refused instead of filling memory.
pub const MAX_INFLATION_RATIO: u64 = 64;

/// One file a scene file names: where (1-based line; 0 when the format has no lines) and
/// the name as written.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reference {
    pub line: usize,
    pub name: String,
}

/// The name without a trailing `.gz` (`box.obj.gz` → `box.obj`), and whether it had one.
pub fn strip_gz(name: &str) -> (&str, bool) {
    match name.len().checked_sub(3).filter(|&i| name.is_char_boundary(i)) {
        Some(i) if name[i..].eq_ignore_ascii_case(".gz") => (&name[..i], true),
        _ => (name, false),
    }
}

/// Inflates gzip `data` (named `name` in errors), refusing more than
/// [`MAX_INFLATED_BYTES`] or [`MAX_INFLATION_RATIO`] times the input. The output grows as
/// bytes arrive; the gzip trailer's size claim is never used to reserve memory.
pub fn inflate(name: &str, data: &[u8]) -> Result<Vec<u8>, SceneError> {
    let cap = (data.len() as u64).saturating_mul(MAX_INFLATION_RATIO).saturating_add(1 << 20).min(MAX_INFLATED_BYTES);
    let mut out = Vec::new();
    let mut dec = flate2::read::MultiGzDecoder::new(data).take(cap + 1);
    dec.read_to_end(&mut out).map_err(|e| SceneError::file(name, format!("not a valid gzip file: {e}")))?;
    if out.len() as u64 > cap {
        return Err(SceneError::file(
            name,
            format!(
                "inflates to more than {cap} bytes ({MAX_INFLATION_RATIO}× the file plus 1 MiB, at most {MAX_INFLATED_BYTES}): refused as a likely gzip bomb"
            ),
        ));
    }
    Ok(out)
}

/// The file with its `.gz` layer removed (name without `.gz`, bytes inflated); other files
/// as they are.
pub fn ungzip(file: &NamedBytes) -> Result<std::borrow::Cow<'_, NamedBytes>, SceneError> {
    match strip_gz(&file.name) {
        (inner, true) => Ok(std::borrow::Cow::Owned(NamedBytes { name: inner.to_string(), data: inflate(&file.name, &file.data)? })),
        _ => Ok(std::borrow::Cow::Borrowed(file)),
    }
}

/// `name` as a clean relative path with `/` separators (`./a\\b.obj` → `a/b.obj`).
fn normalize(name: &str) -> String {
    name.replace('\\', "/").split('/').filter(|c| !c.is_empty() && *c != ".").collect::<Vec<_>>().join("/")
}

/// The file a scene file calls `name` among `files` (the main file is `files[0]` and is
/// not searched): the same relative path, else the same base name (a viewer may have sent
/// it flat), each also with `.gz` appended. `None` when it was not sent.
pub fn find<'a>(files: &'a [NamedBytes], name: &str) -> Option<&'a NamedBytes> {
    let want = normalize(name);
    let rest = files.get(1..).unwrap_or(&[]);
    let base = |s: &str| s.rsplit('/').next().unwrap_or("").to_string();
    let gz = format!("{want}.gz");
    rest.iter()
        .find(|f| normalize(&f.name) == want)
        .or_else(|| rest.iter().find(|f| normalize(&f.name) == gz))
        .or_else(|| rest.iter().find(|f| base(&normalize(&f.name)) == base(&want)))
        .or_else(|| rest.iter().find(|f| base(&normalize(&f.name)) == base(&gz)))
}

/// Every file the main file `main` names, in order, each once. Data URIs and absolute URLs
/// are not files. A main file that cannot be read yet (bad gzip, bad XML) names nothing:
/// the loader reports its error with the file and place.
pub fn references(main: &NamedBytes) -> Vec<Reference> {
    let Ok(file) = ungzip(main) else { return Vec::new() };
    let mut out: Vec<Reference> = match extension(&file.name).as_str() {
        "obj" => super::obj::mtllib_names(&file.data).into_iter().map(|(line, name)| Reference { line, name }).collect(),
        "xml" => super::mitsuba::references(&file.data),
        "gltf" | "glb" => super::gltf::references(&file.data),
        _ => Vec::new(),
    };
    let mut seen = std::collections::HashSet::new();
    out.retain(|r| seen.insert(r.name.clone()));
    out
}

/// Where a file `name` referenced by a scene file in directory `dir` may be read from: a
/// relative path to a file in `dir` or below it. Absolute paths, `..` and symbolic links
/// that lead out of `dir` are refused, so a scene file cannot make a client send arbitrary
/// local files (`mtllib /etc/passwd`, a mesh `../../.ssh/id_rsa`) to a server. The error
/// says why.
pub fn reference_path(dir: &Path, name: &str) -> Result<PathBuf, String> {
    let rel = Path::new(name);
    if rel.is_absolute() || rel.components().any(|c| !matches!(c, Component::Normal(_) | Component::CurDir)) {
        return Err(format!(
            "`{name}` is not a relative path inside the scene file's directory (absolute paths and `..` are refused)"
        ));
    }
    let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
    let path = dir.join(rel);
    let (real_dir, real) = match (dir.canonicalize(), path.canonicalize()) {
        (Ok(d), Ok(p)) => (d, p),
        (_, Err(e)) => return Err(format!("cannot read {}: {e}", path.display())),
        (Err(e), _) => return Err(format!("cannot read {}: {e}", dir.display())),
    };
    if !real.starts_with(&real_dir) {
        return Err(format!("{} leads outside the scene file's directory ({})", path.display(), real.display()));
    }
    if !real.is_file() {
        return Err(format!("{} is not a file", path.display()));
    }
    Ok(path)
}

/// Reads a scene file from disk with every file it references (see [`references`]; each
/// read under [`reference_path`]'s rules, also as `NAME.gz` when `NAME` is absent). The
/// main file is named by its file name, the others as the scene file names them. A
/// reference that may not or cannot be read is a warning naming the file and line — the
/// loader then says what it falls back to (default materials, or an error for a missing
/// mesh).
pub fn gather(path: &Path) -> Result<Vec<NamedBytes>, SceneError> {
    let shown = path.display().to_string();
    let data = std::fs::read(path).map_err(|e| SceneError::file(&shown, format!("cannot read: {e}")))?;
    let main_name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| shown.clone());
    let mut files = vec![NamedBytes { name: main_name, data }];
    let dir = path.parent().unwrap_or(Path::new(""));
    for r in references(&files[0]) {
        let read = |name: &str| reference_path(dir, name).and_then(|p| std::fs::read(&p).map_err(|e| format!("cannot read {}: {e}", p.display())));
        let gz = format!("{}.gz", r.name);
        match read(&r.name).map(|d| (r.name.clone(), d)).or_else(|e| read(&gz).map(|d| (gz.clone(), d)).map_err(|_| e)) {
            Ok((name, data)) => files.push(NamedBytes { name, data }),
            Err(e) => {
                let at = if r.line > 0 { format!(":{}", r.line) } else { String::new() };
                tracing::warn!("{shown}{at}: {} not sent: {e}", r.name)
            }
        }
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nb(name: &str) -> NamedBytes {
        NamedBytes { name: name.into(), data: vec![1] }
    }

    #[test]
    fn names_resolve_by_path_then_base_name_then_gz() {
        let files = [nb("scene.xml"), nb("meshes/a.obj"), nb("b.ply"), nb("sub/c.obj.gz")];
        assert_eq!(find(&files, "./meshes/a.obj").unwrap().name, "meshes/a.obj");
        assert_eq!(find(&files, "meshes\\a.obj").unwrap().name, "meshes/a.obj");
        assert_eq!(find(&files, "other/b.ply").unwrap().name, "b.ply");
        assert_eq!(find(&files, "sub/c.obj").unwrap().name, "sub/c.obj.gz");
        assert!(find(&files, "scene.xml").is_none(), "the main file is not its own reference");
        assert!(find(&files, "d.obj").is_none());
    }

    #[test]
    fn gz_names_and_bounded_inflation() {
        assert_eq!(strip_gz("a.OBJ.GZ"), ("a.OBJ", true));
        assert_eq!(strip_gz("a.obj"), ("a.obj", false));
        assert_eq!(strip_gz("gz"), ("gz", false));
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        std::io::Write::write_all(&mut enc, b"v 0 0 0\n").unwrap();
        let gz = enc.finish().unwrap();
        assert_eq!(inflate("a.gz", &gz).unwrap(), b"v 0 0 0\n");
        // A bomb: 64 MiB of zeros compress to ~64 KiB, past the ratio.
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
        std::io::Write::write_all(&mut enc, &vec![0u8; 64 << 20]).unwrap();
        let bomb = enc.finish().unwrap();
        let e = inflate("bomb.ply.gz", &bomb).unwrap_err().to_string();
        assert!(e.starts_with("bomb.ply.gz: ") && e.contains("gzip bomb"), "{e}");
        let e = inflate("junk.gz", b"not gzip").unwrap_err().to_string();
        assert!(e.contains("junk.gz") && e.contains("gzip"), "{e}");
    }
}
