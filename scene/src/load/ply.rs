//! PLY reader: ASCII, binary little- and big-endian. Reads the `vertex` element's x, y, z
//! (any numeric type) and the `face` element's `vertex_indices` / `vertex_index` list (any
//! count and index type); every other element and property is skipped by its declared type.
//!
//! Hostile headers are the danger here: no count the header or a list claims is trusted for
//! a reservation beyond what the bytes left can hold (a record takes at least
//! [`Element::min_bytes`]), and every record read consumes bytes or fails, so a 121-byte file
//! can neither ask for terabytes nor for 2^64 iterations: it ends in a "truncated" error at
//! the first missing record. Data after the last declared element is an error, not ignored.
use crate::error::{Location, SceneError};
use crate::limits::{check_coordinate, MAX_COORDINATE};
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
    count: u64,
    props: Vec<Property>,
    /// Header line that declared it.
    line: usize,
}

impl Element {
    /// The fewest bytes one record can take: binary, its scalars and list counts (a list
    /// may be empty); ASCII, one character per value plus a separator or line end (an empty
    /// record is still a line).
    fn min_bytes(&self, format: Format) -> u64 {
        match format {
            Format::Ascii => (2 * self.props.len() as u64).max(1),
            _ => self
                .props
                .iter()
                .map(|p| match p {
                    Property::Scalar(_, t) | Property::List(_, t, _) => t.size() as u64,
                })
                .sum(),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Format {
    Ascii,
    Le,
    Be,
}

fn is_face_list(name: &str) -> bool {
    name == "vertex_indices" || name == "vertex_index"
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
        if !face.props.iter().any(|p| matches!(p, Property::List(n, ..) if is_face_list(n))) {
            return Err(SceneError::file(name, "PLY `face` element has no `vertex_indices` list"));
        }
    }
    // Counts are never trusted for a reservation beyond what the bytes after the header can
    // hold (a record takes at least `min_bytes`), and every record read consumes bytes or
    // fails, so a count larger than the file ends in a "truncated" error at the first record
    // that is not there, never in a huge allocation or an endless loop.
    let fits = |e: &Element| (body.len() as u64 + 1) / e.min_bytes(format).max(1);
    let total = elements.iter().fold(0u64, |t, e| t.saturating_add(e.count));
    progress.begin(&format!("parse {name}"), total);
    let mut r = Reader { data: body, pos: 0, base: data.len() - body.len(), format, line: header_lines + 1 };
    let mut positions = Vec::with_capacity(vertex.count.min(fits(vertex)) as usize);
    let mut triangles = Vec::new();
    let mut poly: Vec<u32> = Vec::with_capacity(8);
    let mut values = vec![0f64; vertex.props.len()];
    for e in &elements {
        if e.min_bytes(format) == 0 {
            // Binary records without properties take no bytes: nothing to read, however
            // many the header declares.
            continue;
        }
        for i in 0..e.count {
            let at = |reason: String| SceneError::new(name, Location::Element(e.name.clone(), i as usize), reason);
            if r.at_end() {
                return Err(at(r.place(format!("the file ends here, but the header declares {} `{}` records (truncated)", e.count, e.name))));
            }
            if e.name == "vertex" {
                for (k, p) in e.props.iter().enumerate() {
                    match p {
                        Property::Scalar(_, t) => values[k] = r.scalar(*t).map_err(&at)?,
                        Property::List(_, c, t) => r.skip_list(*c, *t).map_err(&at)?,
                    }
                }
                for &k in &xyz {
                    check_coordinate(values[k], MAX_COORDINATE).map_err(|m| at(r.place(m)))?;
                }
                if positions.len() >= u32::MAX as usize - 1 {
                    return Err(at(r.place("more vertices than a mesh can index (2^32 - 1)".into())));
                }
                positions.push(Vec3::new(values[xyz[0]] as f32, values[xyz[1]] as f32, values[xyz[2]] as f32));
            } else if e.name == "face" {
                for p in &e.props {
                    match p {
                        Property::List(n, c, t) if is_face_list(n) => {
                            let count = r.list_len(*c, *t).map_err(&at)?;
                            poly.clear();
                            for _ in 0..count {
                                let idx = r.scalar(*t).map_err(&at)?;
                                if !(idx >= 0.0 && idx < vertex.count.min(u32::MAX as u64 - 1) as f64 && idx.fract() == 0.0) {
                                    return Err(at(r.place(format!(
                                        "face refers to vertex {idx} but there are {} vertices",
                                        vertex.count
                                    ))));
                                }
                                poly.push(idx as u32);
                            }
                            if poly.len() < 3 {
                                return Err(at(r.place(format!("face has {} vertices; at least 3 are needed", poly.len()))));
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
        progress.advance(e.count % 65536);
    }
    progress.end();
    r.end_of_data(&elements).map_err(|(loc, m)| SceneError::new(name, loc, m))?;
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
                let count = c.parse().map_err(|_| {
                    SceneError::line(name, ln, format!("element count `{c}` is not a whole number in 0..2^64"))
                })?;
                // A second `vertex` (or `face`) would be read with the first one's layout.
                if let Some(first) = elements.iter().find(|e| e.name == *n) {
                    return Err(SceneError::line(
                        name,
                        ln,
                        format!("element `{n}` is declared twice (first on line {})", first.line),
                    ));
                }
                elements.push(Element { name: n.to_string(), count, props: Vec::new(), line: ln });
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
    data: &'a [u8],
    pos: usize,
    base: usize,
    format: Format,
    /// Current text line (ASCII).
    line: usize,
}

impl Reader<'_> {
    /// Whether every byte has been read.
    fn at_end(&self) -> bool {
        self.pos >= self.data.len()
    }

    /// `message` with the place in the file (ASCII line or binary byte offset).
    fn place(&self, message: String) -> String {
        match self.format {
            Format::Ascii => format!("line {}: {message}", self.line),
            _ => format!("byte {}: {message}", self.base + self.pos),
        }
    }

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
                        let mut a = [0u8; std::mem::size_of::<$ty>()];
                        a.copy_from_slice(b);
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

    /// Reads a list's length and checks that its entries fit in the bytes left.
    fn list_len(&mut self, c: Scalar, t: Scalar) -> Result<u64, String> {
        let n = self.scalar(c)?;
        if !(n >= 0.0 && n.fract() == 0.0 && n < u32::MAX as f64) {
            return Err(self.place(format!("invalid list length {n}")));
        }
        let n = n as u64;
        let per = match self.format {
            Format::Ascii => 2,
            _ => t.size() as u64,
        };
        let left = (self.data.len() - self.pos) as u64 + 1;
        if n.saturating_mul(per) > left {
            return Err(self.place(format!("a list of {n} entries does not fit in the {} bytes left (truncated or corrupt)", left - 1)));
        }
        Ok(n)
    }

    fn skip_list(&mut self, c: Scalar, t: Scalar) -> Result<(), String> {
        let n = self.list_len(c, t)?;
        for _ in 0..n {
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
        Ok(())
    }

    /// After the last element: nothing may follow but (ASCII) blank space. More data means
    /// the header's counts are wrong, and silently dropping it would lose geometry.
    fn end_of_data(&self, elements: &[Element]) -> Result<(), (Location, String)> {
        let rest = &self.data[self.pos..];
        let declared = || {
            let counts: Vec<String> = elements.iter().map(|e| format!("{} `{}`", e.count, e.name)).collect();
            if counts.is_empty() {
                "no elements".to_string()
            } else {
                counts.join(", ")
            }
        };
        match self.format {
            Format::Ascii => match rest.iter().position(|b| !b.is_ascii_whitespace()) {
                None => Ok(()),
                Some(k) => {
                    let line = self.line + rest[..k].iter().filter(|&&b| b == b'\n').count();
                    Err((Location::Line(line), format!("data after the last record the header declares ({})", declared())))
                }
            },
            _ if rest.is_empty() => Ok(()),
            _ => Err((
                Location::Byte((self.base + self.pos) as u64),
                format!("{} bytes after the last record the header declares ({})", rest.len(), declared()),
            )),
        }
    }
}
