//! PLY reader: ASCII, binary little- and big-endian. Reads the `vertex` element's x, y, z
//! (any numeric type) and the `face` element's `vertex_indices` / `vertex_index` list (any
//! count and index type); every other element and property is skipped by its declared type.
use crate::error::{Location, SceneError};
use crate::Progress;
use glam::Vec3;

#[derive(Debug, Clone, Copy, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Debug, Clone)]
enum Property {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Format {
    Ascii,
    Le,
    Be,
}

/// Positions and triangles (polygons fan-triangulated) of a PLY file.
pub fn read(name: &str, data: &[u8], progress: &dyn Progress) -> Result<(Vec<Vec3>, Vec<[u32; 3]>), SceneError> {
    let (format, elements, body, header_lines) = header(name, data)?;
    let vertex = elements
        .iter()
        .find(|e| e.name == "vertex")
        .ok_or_else(|| SceneError::file(name, "PLY header has no `vertex` element"))?;
    let coord = |axis: &str| {
        vertex.props.iter().position(|p| matches!(p, Property::Scalar(n, _) if n == axis)).ok_or_else(|| {
            SceneError::file(name, format!("PLY `vertex` element has no scalar property `{axis}`"))
        })
    };
    let xyz = [coord("x")?, coord("y")?, coord("z")?];
    if let Some(face) = elements.iter().find(|e| e.name == "face") {
        if !face.props.iter().any(|p| matches!(p, Property::List(n, ..) if n == "vertex_indices" || n == "vertex_index")) {
            return Err(SceneError::file(name, "PLY `face` element has no `vertex_indices` list"));
        }
    }
    let total: usize = elements.iter().map(|e| e.count).sum();
    progress.begin(&format!("parse {name}"), total as u64);
    let mut r = Reader { name, data: body, pos: 0, base: data.len() - body.len(), format, line: header_lines + 1 };
    let mut positions = Vec::with_capacity(vertex.count);
    let mut triangles = Vec::new();
    let mut poly: Vec<u32> = Vec::with_capacity(8);
    let mut values = vec![0f64; vertex.props.len()];
    for e in &elements {
        for i in 0..e.count {
            let at = |reason: String| SceneError::new(name, Location::Element(e.name.clone(), i), reason);
            if e.name == "vertex" {
                for (k, p) in e.props.iter().enumerate() {
                    match p {
                        Property::Scalar(_, t) => values[k] = r.scalar(*t).map_err(&at)?,
                        Property::List(_, c, t) => r.skip_list(*c, *t).map_err(&at)?,
                    }
                }
                let v = Vec3::new(values[xyz[0]] as f32, values[xyz[1]] as f32, values[xyz[2]] as f32);
                if !v.is_finite() {
                    return Err(at(format!("vertex coordinates are not finite ({v})")));
                }
                positions.push(v);
            } else if e.name == "face" {
                for p in &e.props {
                    match p {
                        Property::List(n, c, t) if n == "vertex_indices" || n == "vertex_index" => {
                            let count = r.scalar(*c).map_err(&at)?;
                            if !(0.0..=1_000_000.0).contains(&count) {
                                return Err(at(format!("face has an invalid vertex count {count}")));
                            }
                            poly.clear();
                            for _ in 0..count as usize {
                                let idx = r.scalar(*t).map_err(&at)?;
                                if !(idx >= 0.0 && idx < positions.len().max(vertex.count) as f64 && idx.fract() == 0.0) {
                                    return Err(at(format!(
                                        "face refers to vertex {idx} but there are {} vertices",
                                        vertex.count
                                    )));
                                }
                                poly.push(idx as u32);
                            }
                            if poly.len() < 3 {
                                return Err(at(format!("face has {} vertices; at least 3 are needed", poly.len())));
                            }
                            for k in 1..poly.len() - 1 {
                                triangles.push([poly[0], poly[k], poly[k + 1]]);
                            }
                        }
                        Property::Scalar(_, t) => {
                            r.scalar(*t).map_err(&at)?;
                        }
                        Property::List(_, c, t) => r.skip_list(*c, *t).map_err(&at)?,
                    }
                }
            } else {
                for p in &e.props {
                    match p {
                        Property::Scalar(_, t) => {
                            r.scalar(*t).map_err(&at)?;
                        }
                        Property::List(_, c, t) => r.skip_list(*c, *t).map_err(&at)?,
                    }
                }
            }
            r.end_record().map_err(at)?;
            if i % 65536 == 65535 {
                progress.advance(65536);
            }
        }
        progress.advance((e.count % 65536) as u64);
    }
    progress.end();
    if triangles.iter().flatten().any(|&v| v as usize >= positions.len()) {
        return Err(SceneError::file(name, "a face refers to a vertex that does not exist"));
    }
    Ok((positions, triangles))
}

/// A parsed header: the format, the elements, the body bytes and the header's line count.
type Header<'a> = (Format, Vec<Element>, &'a [u8], usize);

/// Parses the header.
fn header<'a>(name: &str, data: &'a [u8]) -> Result<Header<'a>, SceneError> {
    if !data.starts_with(b"ply") {
        return Err(SceneError::line(name, 1, "not a PLY file (it does not start with `ply`)"));
    }
    let end = find(data, b"end_header").ok_or_else(|| SceneError::file(name, "PLY header has no `end_header` line"))?;
    let mut body_start = end + b"end_header".len();
    // The header ends with a line break (\n or \r\n).
    if data.get(body_start) == Some(&b'\r') {
        body_start += 1;
    }
    if data.get(body_start) == Some(&b'\n') {
        body_start += 1;
    }
    let text = std::str::from_utf8(&data[..end]).map_err(|_| SceneError::file(name, "PLY header is not text"))?;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut lines = 0;
    for (i, line) in text.lines().enumerate() {
        lines = i + 1;
        let ln = i + 1;
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.first().copied() {
            None | Some("ply") | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                format = Some(match w.get(1).copied() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::Le,
                    Some("binary_big_endian") => Format::Be,
                    other => return Err(SceneError::line(name, ln, format!("unsupported PLY format {other:?}"))),
                })
            }
            Some("element") => {
                let (Some(n), Some(c)) = (w.get(1), w.get(2)) else {
                    return Err(SceneError::line(name, ln, "`element` needs a name and a count"));
                };
                let count = c.parse().map_err(|_| SceneError::line(name, ln, format!("element count `{c}` is not a number")))?;
                elements.push(Element { name: n.to_string(), count, props: Vec::new() });
            }
            Some("property") => {
                let e = elements
                    .last_mut()
                    .ok_or_else(|| SceneError::line(name, ln, "`property` before any `element`"))?;
                let ty = |s: Option<&&str>| {
                    s.and_then(|s| Scalar::parse(s))
                        .ok_or_else(|| SceneError::line(name, ln, format!("unknown property type in `{line}`")))
                };
                if w.get(1) == Some(&"list") {
                    let (c, t) = (ty(w.get(2))?, ty(w.get(3))?);
                    let n = w.get(4).ok_or_else(|| SceneError::line(name, ln, "list property has no name"))?;
                    e.props.push(Property::List(n.to_string(), c, t));
                } else {
                    let t = ty(w.get(1))?;
                    let n = w.get(2).ok_or_else(|| SceneError::line(name, ln, "property has no name"))?;
                    e.props.push(Property::Scalar(n.to_string(), t));
                }
            }
            Some(other) => return Err(SceneError::line(name, ln, format!("unknown PLY header keyword `{other}`"))),
        }
    }
    let format = format.ok_or_else(|| SceneError::file(name, "PLY header has no `format` line"))?;
    Ok((format, elements, &data[body_start..], lines + 1))
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

struct Reader<'a> {
    name: &'a str,
    data: &'a [u8],
    pos: usize,
    base: usize,
    format: Format,
    /// Current text line (ASCII).
    line: usize,
}

impl Reader<'_> {
    fn scalar(&mut self, t: Scalar) -> Result<f64, String> {
        match self.format {
            Format::Ascii => self.ascii_token(),
            _ => {
                let n = t.size();
                let Some(b) = self.data.get(self.pos..self.pos + n) else {
                    return Err(format!("file ends at byte {} (truncated)", self.base + self.data.len()));
                };
                self.pos += n;
                let le = self.format == Format::Le;
                macro_rules! get {
                    ($ty:ty) => {{
                        let a = b.try_into().unwrap();
                        (if le { <$ty>::from_le_bytes(a) } else { <$ty>::from_be_bytes(a) }) as f64
                    }};
                }
                Ok(match t {
                    Scalar::I8 => b[0] as i8 as f64,
                    Scalar::U8 => b[0] as f64,
                    Scalar::I16 => get!(i16),
                    Scalar::U16 => get!(u16),
                    Scalar::I32 => get!(i32),
                    Scalar::U32 => get!(u32),
                    Scalar::F32 => get!(f32),
                    Scalar::F64 => get!(f64),
                })
            }
        }
    }

    fn skip_list(&mut self, c: Scalar, t: Scalar) -> Result<(), String> {
        let n = self.scalar(c)?;
        if !(0.0..=1e7).contains(&n) {
            return Err(format!("invalid list length {n}"));
        }
        for _ in 0..n as usize {
            self.scalar(t)?;
        }
        Ok(())
    }

    /// ASCII records are one line each: a record must not run on, nor leave values over.
    fn ascii_token(&mut self) -> Result<f64, String> {
        let d = self.data;
        while self.pos < d.len() && (d[self.pos] == b' ' || d[self.pos] == b'\t' || d[self.pos] == b'\r') {
            self.pos += 1;
        }
        if self.pos >= d.len() {
            return Err(format!("file ends at line {} (truncated)", self.line));
        }
        if d[self.pos] == b'\n' {
            return Err(format!("line {}: too few values", self.line));
        }
        let start = self.pos;
        while self.pos < d.len() && !d[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let tok = std::str::from_utf8(&d[start..self.pos]).unwrap_or("?");
        tok.parse::<f64>().map_err(|_| format!("line {}: `{tok}` is not a number", self.line))
    }

    fn end_record(&mut self) -> Result<(), String> {
        if self.format != Format::Ascii {
            return Ok(());
        }
        let d = self.data;
        while self.pos < d.len() && (d[self.pos] == b' ' || d[self.pos] == b'\t' || d[self.pos] == b'\r') {
            self.pos += 1;
        }
        if self.pos < d.len() {
            if d[self.pos] != b'\n' {
                return Err(format!("line {}: more values than the header declares", self.line));
            }
            self.pos += 1;
        }
        self.line += 1;
        let _ = self.name;
        Ok(())
    }
}
