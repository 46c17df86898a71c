//! Mitsuba 3 XML scenes: the subset a Cornell-box-class scene uses.
//!
//! - `sensor` perspective (`fov`, `fov_axis` x / y / diagonal / smaller / larger,
//!   `focal_length`, `to_world`) with its `film` `width` / `height`;
//! - `shape` obj / ply (their files are among the scene's files, see [`super::files`]),
//!   rectangle, cube, sphere, disk, each with `to_world`, a `bsdf` or a `ref` to one, and an
//!   `area` emitter (its triangles become area lights, merged into convex polygons);
//! - `bsdf` diffuse, conductor / roughconductor (`material` names, `eta` / `k`, `alpha`),
//!   dielectric / roughdielectric (`int_ior` / `ext_ior` numbers or names), plastic /
//!   roughplastic, twosided; `bitmap` reflectance textures;
//! - `emitter` point and spot; directional (a distant point light) and constant (the
//!   ambient term) with a warning;
//! - `transform` with `translate`, `rotate`, `scale`, `matrix`, `lookat`;
//! - `rgb`, `float` and `spectrum` values (wavelength:value lists converted as Mitsuba's RGB
//!   variants do, see [`super::spectrum`]); `default` parameters and `$name` references.
//!
//! Anything else is named in a warning and replaced by the nearest supported thing (an
//! unknown BSDF by its nested BSDF or a grey diffuse, an unsupported shape skipped).
//! Errors name the file and line. Plain Mitsuba BSDFs are one-sided (`two_sided: false`);
//! `twosided` makes them two-sided.
use super::emitters::area_lights;
use super::files::{find, Reference};
use super::spectrum::{spectrum_to_rgb, uniform_to_rgb, SpectrumKind};
use super::{stage_meshes, FileView, NamedBytes};
use crate::{Bsdf, Camera, Corners, Light, Material, Mesh, Object, Progress, Scene, SceneError, Texture};
use glam::{Affine3A, DMat4, DVec3, Vec2, Vec3};
use roxmltree::{Document, Node};
use std::collections::HashMap;
use std::sync::Arc;

/// Parsing state: the file, its `default` parameters and every element with an `id`.
struct Ctx<'a, 'input> {
    name: &'a str,
    doc: &'a Document<'input>,
    defaults: HashMap<String, String>,
    ids: HashMap<String, Node<'a, 'input>>,
    files: &'a [NamedBytes],
}

fn parse_document<'i>(name: &str, data: &'i [u8]) -> Result<Document<'i>, SceneError> {
    let text = std::str::from_utf8(data).map_err(|e| SceneError::file(name, format!("not UTF-8 text: {e}")))?;
    Document::parse(text).map_err(|e| SceneError::line(name, e.pos().row as usize, format!("XML: {e}")))
}

impl<'a, 'input> Ctx<'a, 'input> {
    fn new(name: &'a str, doc: &'a Document<'input>, files: &'a [NamedBytes]) -> Result<Self, SceneError> {
        let mut c = Ctx { name, doc, defaults: HashMap::new(), ids: HashMap::new(), files };
        let root = doc.root_element();
        if root.tag_name().name() != "scene" {
            return Err(c.err(root, format!("the root element is <{}>, not <scene>", root.tag_name().name())));
        }
        for n in root.children().filter(|n| n.has_tag_name("default")) {
            let key = n.attribute("name").ok_or_else(|| c.err(n, "<default> needs a name"))?;
            let value = n.attribute("value").ok_or_else(|| c.err(n, "<default> needs a value"))?;
            c.defaults.insert(key.to_string(), value.to_string());
        }
        for n in root.descendants().filter(|n| n.is_element()) {
            // Every `$name` must be defined, used or not (as in Mitsuba).
            for a in n.attributes() {
                c.subst(n, a.value())?;
            }
            // A <ref> carries the id it refers to, not one of its own.
            if let Some(id) = n.attribute("id").filter(|_| !n.has_tag_name("ref")) {
                let id = c.subst(n, id)?;
                c.ids.insert(id, n);
            }
        }
        Ok(c)
    }

    fn line(&self, n: Node) -> usize {
        self.doc.text_pos_at(n.range().start).row as usize
    }

    fn err(&self, n: Node, msg: impl Into<String>) -> SceneError {
        SceneError::line(self.name, self.line(n), msg)
    }

    fn warn(&self, n: Node, msg: impl std::fmt::Display) {
        tracing::warn!("{}:{}: {msg}", self.name, self.line(n));
    }

    /// `value` with every `$name` replaced by its `default` (longest names first, so `$res`
    /// does not eat `$resolution`). An undefined `$name` is an error.
    fn subst(&self, n: Node, value: &str) -> Result<String, SceneError> {
        if !value.contains('$') {
            return Ok(value.to_string());
        }
        let mut out = String::new();
        let mut rest = value;
        while let Some(i) = rest.find('$') {
            out.push_str(&rest[..i]);
            let after = &rest[i + 1..];
            let len = after.find(|c: char| !(c.is_alphanumeric() || c == '_')).unwrap_or(after.len());
            let key = &after[..len];
            let mut keys: Vec<&String> = self.defaults.keys().filter(|k| key.starts_with(k.as_str())).collect();
            keys.sort_by_key(|k| std::cmp::Reverse(k.len()));
            match keys.first() {
                Some(k) => {
                    out.push_str(&self.defaults[*k]);
                    rest = &after[k.len()..];
                }
                None => return Err(self.err(n, format!("`${key}` is not a defined parameter (no <default name=\"{key}\">)"))),
            }
        }
        out.push_str(rest);
        Ok(out)
    }

    fn attr(&self, n: Node, key: &str) -> Result<Option<String>, SceneError> {
        n.attribute(key).map(|v| self.subst(n, v)).transpose()
    }

    fn need(&self, n: Node, key: &str) -> Result<String, SceneError> {
        self.attr(n, key)?.ok_or_else(|| self.err(n, format!("<{}> needs a `{key}` attribute", n.tag_name().name())))
    }

    /// The child property element called `name` (`<float name="fov" .../>` etc.).
    fn prop(&self, n: Node<'a, 'input>, name: &str) -> Option<Node<'a, 'input>> {
        n.children().find(|c| c.is_element() && c.attribute("name") == Some(name))
    }

    fn number(&self, n: Node, text: &str, what: &str) -> Result<f64, SceneError> {
        let v: f64 = text.trim().parse().map_err(|_| self.err(n, format!("{what} `{}` is not a number", text.trim())))?;
        if !v.is_finite() {
            return Err(self.err(n, format!("{what} `{}` is not finite", text.trim())));
        }
        Ok(v)
    }

    /// Numbers separated by commas and/or spaces.
    fn numbers(&self, n: Node, text: &str, what: &str) -> Result<Vec<f64>, SceneError> {
        text.split(|c: char| c == ',' || c.is_whitespace()).filter(|t| !t.is_empty()).map(|t| self.number(n, t, what)).collect()
    }

    fn float(&self, n: Node<'a, 'input>, name: &str, default: f64) -> Result<f64, SceneError> {
        match self.prop(n, name) {
            Some(p) => {
                let v = self.need(p, "value")?;
                self.number(p, &v, name)
            }
            None => Ok(default),
        }
    }

    fn string(&self, n: Node<'a, 'input>, name: &str) -> Result<Option<String>, SceneError> {
        match self.prop(n, name) {
            Some(p) => Ok(Some(self.need(p, "value")?)),
            None => Ok(None),
        }
    }

    fn boolean(&self, n: Node<'a, 'input>, name: &str) -> Result<bool, SceneError> {
        match self.string(n, name)? {
            None => Ok(false),
            Some(v) => match v.trim() {
                "true" => Ok(true),
                "false" => Ok(false),
                other => Err(self.err(self.prop(n, name).unwrap_or(n), format!("boolean `{other}` is neither true nor false"))),
            },
        }
    }

    /// A point or vector: `x`, `y`, `z` attributes (missing ones `default`) or `value`.
    fn xyz(&self, n: Node, default: f64) -> Result<DVec3, SceneError> {
        if let Some(v) = self.attr(n, "value")? {
            let v = self.numbers(n, &v, "value")?;
            return match v.len() {
                1 => Ok(DVec3::splat(v[0])),
                3 => Ok(DVec3::new(v[0], v[1], v[2])),
                k => Err(self.err(n, format!("expected 1 or 3 numbers, got {k}"))),
            };
        }
        let mut out = DVec3::splat(default);
        for (i, k) in ["x", "y", "z"].into_iter().enumerate() {
            if let Some(v) = self.attr(n, k)? {
                out[i] = self.number(n, &v, k)?;
            }
        }
        Ok(out)
    }

    fn point(&self, n: Node<'a, 'input>, name: &str, default: DVec3) -> Result<DVec3, SceneError> {
        match self.prop(n, name) {
            Some(p) => self.xyz(p, 0.0),
            None => Ok(default),
        }
    }

    /// A `<transform>`: its operations applied in order (each after the ones before).
    fn transform(&self, t: Node) -> Result<DMat4, SceneError> {
        let mut m = DMat4::IDENTITY;
        for op in t.children().filter(|c| c.is_element()) {
            let step = match op.tag_name().name() {
                "translate" => DMat4::from_translation(self.xyz(op, 0.0)?),
                "scale" => DMat4::from_scale(self.xyz(op, 1.0)?),
                "rotate" => {
                    let axis = self.xyz(op, 0.0)?;
                    let angle = self.number(op, &self.need(op, "angle")?, "angle")?;
                    if axis.length() == 0.0 {
                        return Err(self.err(op, "rotation axis is zero"));
                    }
                    DMat4::from_axis_angle(axis.normalize(), angle.to_radians())
                }
                "matrix" => {
                    let v = self.numbers(op, &self.need(op, "value")?, "matrix entry")?;
                    match v.len() {
                        16 => DMat4::from_cols_array(&[
                            v[0], v[4], v[8], v[12], v[1], v[5], v[9], v[13], v[2], v[6], v[10], v[14], v[3], v[7], v[11], v[15],
                        ]),
                        9 => DMat4::from_cols_array(&[
                            v[0], v[3], v[6], 0.0, v[1], v[4], v[7], 0.0, v[2], v[5], v[8], 0.0, 0.0, 0.0, 0.0, 1.0,
                        ]),
                        k => return Err(self.err(op, format!("a matrix needs 16 (or 9) numbers, got {k}"))),
                    }
                }
                "lookat" => {
                    let get = |k: &str| -> Result<DVec3, SceneError> {
                        let v = self.numbers(op, &self.need(op, k)?, k)?;
                        if v.len() != 3 {
                            return Err(self.err(op, format!("lookat {k} needs 3 numbers, got {}", v.len())));
                        }
                        Ok(DVec3::new(v[0], v[1], v[2]))
                    };
                    let (origin, target) = (get("origin")?, get("target")?);
                    let up = if op.attribute("up").is_some() { get("up")? } else { DVec3::Y };
                    let dir = (target - origin).normalize_or_zero();
                    let left = up.cross(dir).normalize_or_zero();
                    if dir == DVec3::ZERO || left == DVec3::ZERO {
                        return Err(self.err(op, "lookat: origin equals target, or up is parallel to the view direction"));
                    }
                    let new_up = dir.cross(left);
                    DMat4::from_cols(left.extend(0.0), new_up.extend(0.0), dir.extend(0.0), origin.extend(1.0))
                }
                other => {
                    self.warn(op, format!("transform operation <{other}> is not supported: ignored"));
                    DMat4::IDENTITY
                }
            };
            m = step * m;
        }
        if !m.is_finite() {
            return Err(self.err(t, "transform is not finite"));
        }
        Ok(m)
    }

    fn to_world(&self, n: Node<'a, 'input>) -> Result<DMat4, SceneError> {
        match n.children().find(|c| c.has_tag_name("transform") && c.attribute("name") == Some("to_world")) {
            Some(t) => self.transform(t),
            None => Ok(DMat4::IDENTITY),
        }
    }

    /// A colour-valued property (`rgb`, `spectrum`, `float`; a `texture` gives its mean with
    /// a warning unless the caller handles bitmaps) or `default`.
    fn color(&self, n: Node<'a, 'input>, name: &str, default: Vec3, kind: SpectrumKind) -> Result<Vec3, SceneError> {
        let Some(p) = self.prop(n, name).or_else(|| self.referenced_prop(n, name)) else { return Ok(default) };
        self.color_value(p, kind)
    }

    /// `<ref name="NAME" id="..."/>` naming a texture or spectrum defined elsewhere.
    fn referenced_prop(&self, n: Node<'a, 'input>, name: &str) -> Option<Node<'a, 'input>> {
        let r = n.children().find(|c| c.has_tag_name("ref") && c.attribute("name") == Some(name))?;
        self.ids.get(r.attribute("id")?).copied()
    }

    fn color_value(&self, p: Node<'a, 'input>, kind: SpectrumKind) -> Result<Vec3, SceneError> {
        match p.tag_name().name() {
            "rgb" => {
                let v = self.numbers(p, &self.need(p, "value")?, "colour component")?;
                match v.len() {
                    1 => Ok(Vec3::splat(v[0] as f32)),
                    3 => Ok(Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32)),
                    k => Err(self.err(p, format!("rgb needs 1 or 3 numbers, got {k}"))),
                }
            }
            "float" => Ok(uniform_to_rgb(self.number(p, &self.need(p, "value")?, "value")?, kind)),
            "spectrum" => {
                if p.attribute("filename").is_some() {
                    self.warn(p, "spectrum files are not supported: using a flat spectrum of 1 instead");
                    return Ok(uniform_to_rgb(1.0, kind));
                }
                if p.attribute("type").is_some() {
                    self.warn(p, format!("spectrum type `{}` is not supported: using a flat spectrum of 1 instead", p.attribute("type").unwrap_or("")));
                    return Ok(uniform_to_rgb(1.0, kind));
                }
                let v = self.need(p, "value")?;
                if !v.contains(':') {
                    return Ok(uniform_to_rgb(self.number(p, &v, "spectrum value")?, kind));
                }
                let mut pairs = Vec::new();
                for tok in v.split(',').map(str::trim).filter(|t| !t.is_empty()) {
                    let (w, x) = tok.split_once(':').ok_or_else(|| self.err(p, format!("`{tok}` is not a wavelength:value pair")))?;
                    let (w, x) = (self.number(p, w, "wavelength")?, self.number(p, x, "spectrum value")?);
                    if let Some(&(last, _)) = pairs.last() {
                        if !(w > last) {
                            return Err(self.err(p, format!("wavelengths must increase ({w} after {last})")));
                        }
                    }
                    pairs.push((w, x));
                }
                Ok(spectrum_to_rgb(&pairs, kind))
            }
            "texture" => {
                self.warn(p, format!("texture `{}` used where only a colour is supported: using its mean", p.attribute("type").unwrap_or("")));
                Ok(self.texture(p)?.map(|t| mean(&t)).unwrap_or(Vec3::splat(0.5)))
            }
            other => Err(self.err(p, format!("<{other}> is not a colour (rgb, spectrum or float)"))),
        }
    }

    /// A `<texture>`: `bitmap` decoded (sRGB to linear unless `raw`), `checkerboard` and
    /// others approximated by a flat mean colour with a warning (`None` → 0.5 grey).
    fn texture(&self, t: Node<'a, 'input>) -> Result<Option<Arc<Texture>>, SceneError> {
        match t.attribute("type") {
            Some("bitmap") => {
                let file = self.string(t, "filename")?.ok_or_else(|| self.err(t, "bitmap texture needs a filename"))?;
                let Some(f) = find(self.files, &file) else {
                    self.warn(t, format!("texture {file} was not sent with the scene: using 0.5 grey"));
                    return Ok(None);
                };
                let raw = self.boolean(t, "raw")?;
                // Mitsuba's UVs run like OBJ's (v up): row 0 of the texture is the image's
                // bottom row.
                super::gltf::decode_texture(f, !raw, true).map(|t| Some(Arc::new(t)))
            }
            Some("checkerboard") => {
                self.warn(t, "checkerboard texture is not supported: using the mean of its two colours");
                let a = self.color(t, "color0", Vec3::splat(0.4), SpectrumKind::Reflectance)?;
                let b = self.color(t, "color1", Vec3::splat(0.2), SpectrumKind::Reflectance)?;
                Ok(Some(Arc::new(Texture { name: "checkerboard".into(), width: 1, height: 1, texels: vec![(a + b) * 0.5] })))
            }
            other => {
                self.warn(t, format!("texture type `{}` is not supported: using 0.5 grey", other.unwrap_or("")));
                Ok(None)
            }
        }
    }

    /// A reflectance that may be a texture: (colour, texture). A texture's colour is 1 (it
    /// multiplies).
    fn reflectance(&self, n: Node<'a, 'input>, name: &str, default: Vec3) -> Result<(Vec3, Option<Arc<Texture>>), SceneError> {
        match self.prop(n, name).or_else(|| self.referenced_prop(n, name)) {
            Some(p) if p.has_tag_name("texture") && p.attribute("type") == Some("bitmap") => match self.texture(p)? {
                Some(t) => Ok((Vec3::ONE, Some(t))),
                None => Ok((Vec3::splat(0.5), None)),
            },
            Some(p) => Ok((self.color_value(p, SpectrumKind::Reflectance)?.clamp(Vec3::ZERO, Vec3::ONE), None)),
            None => Ok((default, None)),
        }
    }

    /// An index of refraction: a number or one of Mitsuba's named materials.
    fn ior(&self, n: Node<'a, 'input>, name: &str, default: f64) -> Result<f64, SceneError> {
        let Some(p) = self.prop(n, name) else { return Ok(default) };
        let v = self.need(p, "value")?;
        if let Ok(x) = v.trim().parse::<f64>() {
            if !(x > 0.0 && x.is_finite()) {
                return Err(self.err(p, format!("{name} must be a positive number, got {x}")));
            }
            return Ok(x);
        }
        named_ior(v.trim()).ok_or_else(|| {
            self.err(p, format!("{name} `{}` is not a number or a known material ({})", v.trim(), IORS.iter().map(|i| i.0).collect::<Vec<_>>().join(", ")))
        })
    }

    fn alpha(&self, b: Node<'a, 'input>) -> Result<f32, SceneError> {
        if let Some(d) = self.string(b, "distribution")? {
            if d != "ggx" {
                self.warn(b, format!("microfacet distribution `{d}` is approximated by GGX with the same alpha"));
            }
        }
        if self.prop(b, "alpha_u").is_some() || self.prop(b, "alpha_v").is_some() {
            let (u, v) = (self.float(b, "alpha_u", 0.1)?, self.float(b, "alpha_v", 0.1)?);
            self.warn(b, format!("anisotropic roughness (alpha_u {u}, alpha_v {v}) is approximated by the isotropic alpha {}", (u * v).sqrt()));
            return Ok((u * v).sqrt() as f32);
        }
        let a = self.float(b, "alpha", 0.1)?;
        if !(0.0..=1.0).contains(&a) {
            return Err(self.err(self.prop(b, "alpha").unwrap_or(b), format!("alpha must be in [0, 1], got {a}")));
        }
        Ok(a as f32)
    }

    /// The material a `<bsdf>` describes (`name` for the material when it has no id).
    fn bsdf(&self, b: Node<'a, 'input>, depth: usize) -> Result<Material, SceneError> {
        if depth > 8 {
            return Err(self.err(b, "BSDFs nested more than 8 deep (a reference cycle?)"));
        }
        let ty = self.need(b, "type")?;
        let name = self.attr(b, "id")?.unwrap_or_else(|| ty.clone());
        let base = |bsdf: Bsdf, diffuse: Vec3, texture: Option<Arc<Texture>>| Material {
            name: name.clone(),
            diffuse,
            texture,
            bsdf,
            two_sided: false,
            emission: Vec3::ZERO,
        };
        let nested = || -> Option<Node<'a, 'input>> {
            b.children().find(|c| c.has_tag_name("bsdf")).or_else(|| {
                let r = b.children().find(|c| c.has_tag_name("ref"))?;
                self.ids.get(r.attribute("id")?).copied().filter(|n| n.has_tag_name("bsdf"))
            })
        };
        Ok(match ty.as_str() {
            "twosided" => {
                let inner = nested().ok_or_else(|| self.err(b, "twosided needs a nested <bsdf> (or a <ref> to one)"))?;
                let mut m = self.bsdf(inner, depth + 1)?;
                m.two_sided = true;
                if let Some(id) = self.attr(b, "id")? {
                    m.name = id;
                }
                m
            }
            "diffuse" => {
                let (c, t) = self.reflectance(b, "reflectance", Vec3::splat(0.5))?;
                base(Bsdf::Diffuse, c, t)
            }
            "conductor" | "roughconductor" => {
                let roughness = if ty == "roughconductor" { self.alpha(b)? } else { 0.0 };
                let material = self.string(b, "material")?.unwrap_or_else(|| "none".into());
                let (mut eta, mut k) = match conductor(&material) {
                    Some(ek) => ek,
                    None => {
                        self.warn(b, format!("conductor material `{material}` is not known here: using aluminium (known: {})", CONDUCTORS.iter().map(|c| c.0).collect::<Vec<_>>().join(", ")));
                        conductor("Al").expect("aluminium is in the table")
                    }
                };
                if self.prop(b, "eta").is_some() || self.prop(b, "k").is_some() {
                    eta = self.color(b, "eta", eta, SpectrumKind::Emitter)?;
                    k = self.color(b, "k", k, SpectrumKind::Emitter)?;
                }
                let (c, t) = self.reflectance(b, "specular_reflectance", Vec3::ONE)?;
                base(Bsdf::Conductor { eta, k, roughness }, c, t)
            }
            "dielectric" | "roughdielectric" | "thindielectric" => {
                if ty == "thindielectric" {
                    self.warn(b, "thindielectric is approximated by a smooth dielectric");
                }
                let roughness = if ty == "roughdielectric" { self.alpha(b)? } else { 0.0 };
                let ior = self.ior(b, "int_ior", 1.5046)? / self.ior(b, "ext_ior", 1.000277)?;
                let (c, t) = self.reflectance(b, "specular_transmittance", Vec3::ONE)?;
                base(Bsdf::Dielectric { ior: ior as f32, roughness }, c, t)
            }
            "plastic" | "roughplastic" => {
                let roughness = if ty == "roughplastic" { self.alpha(b)? } else { 0.0 };
                let ior = self.ior(b, "int_ior", 1.49)? / self.ior(b, "ext_ior", 1.000277)?;
                let (c, t) = self.reflectance(b, "diffuse_reflectance", Vec3::splat(0.5))?;
                base(Bsdf::Plastic { ior: ior as f32, roughness }, c, t)
            }
            other => match nested() {
                Some(inner) => {
                    self.warn(b, format!("BSDF type `{other}` is not supported: using the BSDF it wraps"));
                    self.bsdf(inner, depth + 1)?
                }
                None => {
                    let (c, t) = self.reflectance(b, "base_color", Vec3::splat(0.5))?;
                    self.warn(b, format!("BSDF type `{other}` is not supported: using a diffuse of its base colour ({c})"));
                    base(Bsdf::Diffuse, c, t)
                }
            },
        })
    }

    /// The material of a shape: its nested `<bsdf>`, the `<ref>` one, or Mitsuba's default
    /// (a 0.5 grey diffuse).
    fn shape_material(&self, s: Node<'a, 'input>) -> Result<Material, SceneError> {
        if let Some(b) = s.children().find(|c| c.has_tag_name("bsdf")) {
            return self.bsdf(b, 0);
        }
        for r in s.children().filter(|c| c.has_tag_name("ref")) {
            let id = self.need(r, "id")?;
            match self.ids.get(&id) {
                Some(b) if b.has_tag_name("bsdf") => return self.bsdf(*b, 0),
                Some(_) => {}
                None => return Err(self.err(r, format!("no element has id `{id}`"))),
            }
        }
        Ok(Material { two_sided: false, ..Material::diffuse("default", Vec3::splat(0.5)) })
    }

    /// The sensor's camera and film size. `fov` is converted to the vertical field of view
    /// of the film's aspect ratio.
    fn sensor(&self, s: Node<'a, 'input>) -> Result<(Camera, (u32, u32)), SceneError> {
        let ty = self.need(s, "type")?;
        if ty != "perspective" {
            self.warn(s, format!("sensor type `{ty}` is not supported: rendered as a perspective camera with its transform and field of view"));
        }
        let (mut w, mut h) = (768u32, 576u32);
        if let Some(f) = s.children().find(|c| c.has_tag_name("film")) {
            let size = |k: &str, d: u32| -> Result<u32, SceneError> {
                let v = self.float(f, k, d as f64)?;
                if !((1.0..=16384.0).contains(&v) && v.fract() == 0.0) {
                    return Err(self.err(self.prop(f, k).unwrap_or(f), format!("film {k} must be a whole number in 1..=16384, got {v}")));
                }
                Ok(v as u32)
            };
            (w, h) = (size("width", 768)?, size("height", 576)?);
        }
        let aspect = w as f64 / h as f64;
        let (fov, axis) = match (self.prop(s, "fov"), self.string(s, "focal_length")?) {
            (Some(_), _) => (self.float(s, "fov", 0.0)?, self.string(s, "fov_axis")?.unwrap_or_else(|| "x".into())),
            (None, Some(fl)) => {
                let mm = self.number(s, fl.trim().trim_end_matches("mm"), "focal_length")?;
                // A 35 mm film's diagonal.
                (2.0 * (36f64.hypot(24.0) / (2.0 * mm)).atan().to_degrees(), "diagonal".to_string())
            }
            (None, None) => (2.0 * (36f64.hypot(24.0) / 100.0).atan().to_degrees(), "diagonal".to_string()),
        };
        if !(fov > 0.0 && fov < 180.0) {
            return Err(self.err(self.prop(s, "fov").unwrap_or(s), format!("fov must be in (0, 180) degrees, got {fov}")));
        }
        let t = (fov.to_radians() * 0.5).tan();
        let tan_y = match axis.as_str() {
            "x" => t / aspect,
            "y" => t,
            "diagonal" => t / (1.0 + aspect * aspect).sqrt(),
            "smaller" => if aspect >= 1.0 { t } else { t / aspect },
            "larger" => if aspect >= 1.0 { t / aspect } else { t },
            other => return Err(self.err(s, format!("fov_axis `{other}` is not one of x, y, diagonal, smaller, larger"))),
        };
        let m = self.to_world(s)?;
        let eye = m.transform_point3(DVec3::ZERO);
        let dir = m.transform_vector3(DVec3::Z).normalize_or_zero();
        let up = m.transform_vector3(DVec3::Y).normalize_or_zero();
        if m.determinant() < 0.0 {
            self.warn(s, "the camera transform mirrors the image; edgepoint renders it unmirrored");
        }
        let camera = Camera {
            eye: eye.as_vec3(),
            target: (eye + dir).as_vec3(),
            up: up.as_vec3(),
            fov_y_degrees: (2.0 * tan_y.atan()).to_degrees() as f32,
        };
        camera.validate().map_err(|e| self.err(s, e))?;
        Ok((camera, (w, h)))
    }

    fn find_sensor(&self, camera_name: Option<&str>) -> Result<Option<Node<'a, 'input>>, SceneError> {
        let sensors: Vec<Node> = self.doc.root_element().children().filter(|c| c.has_tag_name("sensor")).collect();
        match camera_name {
            None => Ok(sensors.first().copied()),
            Some(want) => sensors.iter().copied().find(|s| s.attribute("id") == Some(want)).map(Some).ok_or_else(|| {
                let ids: Vec<&str> = sensors.iter().filter_map(|s| s.attribute("id")).collect();
                SceneError::file(self.name, format!("no sensor has id `{want}` (sensor ids: {})", if ids.is_empty() { "none".into() } else { ids.join(", ") }))
            }),
        }
    }

    /// The mesh of a shape and the transform from its mesh to the shape's object space (a
    /// sphere's centre and radius), or `None` (with a warning) for a shape type that is not
    /// supported. Meshes are shared through `cache`: every sphere of a scene is one unit
    /// sphere, a mesh file used by several shapes is read once, so a small XML cannot
    /// multiply geometry (or memory) by repeating a shape.
    fn shape_mesh(
        &self,
        s: Node<'a, 'input>,
        ty: &str,
        cache: &mut HashMap<String, Arc<Mesh>>,
        progress: &dyn Progress,
    ) -> Result<Option<(Arc<Mesh>, DMat4)>, SceneError> {
        use crate::builtin::shapes;
        let flip = self.boolean(s, "flip_normals")?;
        let mut pre = DMat4::IDENTITY;
        let key = match ty {
            "obj" | "ply" => {
                let file = self.string(s, "filename")?.ok_or_else(|| self.err(s, format!("{ty} shape needs a filename")))?;
                format!("{ty} {file} {} {flip}", self.boolean(s, "face_normals")?)
            }
            "sphere" => {
                let centre = self.point(s, "center", DVec3::ZERO)?;
                let r = self.float(s, "radius", 1.0)?;
                if !(r > 0.0) {
                    return Err(self.err(s, format!("sphere radius must be positive, got {r}")));
                }
                pre = DMat4::from_translation(centre) * DMat4::from_scale(DVec3::splat(r));
                format!("sphere {flip}")
            }
            "rectangle" | "disk" | "cube" => format!("{ty} {flip}"),
            other => {
                self.warn(s, format!("shape type `{other}` is not supported: skipped (supported: obj, ply, rectangle, cube, sphere, disk)"));
                return Ok(None);
            }
        };
        if let Some(m) = cache.get(&key) {
            return Ok(Some((m.clone(), pre)));
        }
        let mut mesh = match ty {
            "obj" | "ply" => {
                let file = self.string(s, "filename")?.unwrap_or_default();
                let f = find(self.files, &file).ok_or_else(|| {
                    self.err(s, format!("mesh file {file} was not sent with the scene (is it next to the XML file, inside its directory?)"))
                })?;
                let mut m = super::mesh_from_file(f, progress)?;
                if self.boolean(s, "face_normals")? {
                    m.corners.normals = None;
                }
                m
            }
            "rectangle" => {
                let p = vec![Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(-1.0, 1.0, 0.0)];
                let uv = [Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)];
                let corners = Corners { normals: None, uvs: Some(vec![[uv[0], uv[1], uv[2]], [uv[0], uv[2], uv[3]]]) };
                Mesh::from_triangles_with_corners(p, vec![[0, 1, 2], [0, 2, 3]], corners, &crate::NoProgress)
            }
            "disk" => {
                let p: Vec<Vec3> = (0..64)
                    .map(|i| {
                        let a = std::f32::consts::TAU * i as f32 / 64.0;
                        Vec3::new(a.cos(), a.sin(), 0.0)
                    })
                    .collect();
                shapes::polygon(&p)
            }
            "cube" => shapes::cuboid(Vec3::splat(-1.0), Vec3::ONE),
            _ => {
                let unit = shapes::sphere(1.0, 48, 24);
                // Smooth shading: the unit sphere's normal at a corner is its position.
                let normals = unit.triangles.iter().map(|t| t.map(|i| unit.positions[i as usize].normalize())).collect();
                Mesh::from_triangles_with_corners(unit.positions.clone(), unit.triangles.clone(), Corners { normals: Some(normals), uvs: None }, &crate::NoProgress)
            }
        };
        if flip {
            mesh.flip();
            if let Some(n) = &mut mesh.corners.normals {
                n.iter_mut().flatten().for_each(|v| *v = -*v);
            }
        }
        let mesh = Arc::new(mesh);
        cache.insert(key, mesh.clone());
        Ok(Some((mesh, pre)))
    }

    /// An emitter's radiance or intensity property.
    fn emitted(&self, e: Node<'a, 'input>, name: &str) -> Result<Vec3, SceneError> {
        let c = self.color(e, name, Vec3::ONE, SpectrumKind::Emitter)?;
        if !(c.is_finite() && c.min_element() >= 0.0) {
            return Err(self.err(e, format!("{name} must be finite and non-negative, got {c}")));
        }
        Ok(c)
    }
}

fn mean(t: &Texture) -> Vec3 {
    t.texels.iter().copied().sum::<Vec3>() / t.texels.len().max(1) as f32
}

fn affine(m: &DMat4) -> Affine3A {
    Affine3A::from_mat4(m.as_mat4())
}

/// Indices of refraction by Mitsuba's names (its `ior` table).
const IORS: &[(&str, f64)] = &[
    ("vacuum", 1.0),
    ("helium", 1.000036),
    ("hydrogen", 1.000132),
    ("air", 1.000277),
    ("carbon dioxide", 1.00045),
    ("water", 1.3330),
    ("acetone", 1.36),
    ("ethanol", 1.361),
    ("carbon tetrachloride", 1.461),
    ("glycerol", 1.4729),
    ("benzene", 1.501),
    ("silicone oil", 1.52045),
    ("bromine", 1.661),
    ("water ice", 1.31),
    ("fused quartz", 1.458),
    ("pyrex", 1.470),
    ("acrylic glass", 1.49),
    ("polypropylene", 1.49),
    ("bk7", 1.5046),
    ("sodium chloride", 1.544),
    ("amber", 1.55),
    ("pet", 1.5750),
    ("diamond", 2.419),
];

fn named_ior(name: &str) -> Option<f64> {
    IORS.iter().find(|i| i.0.eq_ignore_ascii_case(name)).map(|i| i.1)
}

/// Complex indices of refraction (eta, k) in linear sRGB for Mitsuba's conductor names:
/// its measured spectra reduced to RGB as its RGB variants do (unbounded, no D65).
/// `none` is Mitsuba's perfect mirror.
const CONDUCTORS: &[(&str, [f32; 3], [f32; 3])] = &[
    ("none", [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
    ("Ag", [0.1553, 0.1167, 0.1384], [4.8284, 3.1222, 2.1469]),
    ("Al", [1.6574, 0.8803, 0.5212], [9.2238, 6.2695, 4.8370]),
    ("Au", [0.1431, 0.3749, 1.4425], [3.9831, 2.3857, 1.6032]),
    ("Cu", [0.2004, 0.9240, 1.1022], [3.9129, 2.4528, 2.1421]),
    ("CuZn", [0.4440, 0.5270, 1.0940], [3.6950, 2.7650, 1.8290]),
    ("Cr", [4.3696, 2.9167, 1.6547], [5.2064, 4.2313, 3.7549]),
];

fn conductor(name: &str) -> Option<(Vec3, Vec3)> {
    CONDUCTORS.iter().find(|c| c.0 == name).map(|c| (Vec3::from(c.1), Vec3::from(c.2)))
}

/// Every file a Mitsuba scene names (`<string name="filename">` of shapes and textures),
/// with `$name` parameters substituted.
pub fn references(data: &[u8]) -> Vec<Reference> {
    let Ok(doc) = parse_document("", data) else { return Vec::new() };
    let Ok(ctx) = Ctx::new("", &doc, &[]) else { return Vec::new() };
    doc.descendants()
        .filter(|n| n.has_tag_name("string") && n.attribute("name") == Some("filename"))
        .filter(|n| n.parent_element().is_some_and(|p| p.has_tag_name("shape") || p.has_tag_name("texture")))
        .filter_map(|n| Some(Reference { line: ctx.line(n), name: ctx.attr(n, "value").ok()?? }))
        .collect()
}

/// The camera and film of a Mitsuba scene.
pub fn view(main: &NamedBytes, camera_name: Option<&str>) -> Result<FileView, SceneError> {
    let doc = parse_document(&main.name, &main.data)?;
    let ctx = Ctx::new(&main.name, &doc, &[])?;
    match ctx.find_sensor(camera_name)? {
        Some(s) => {
            let (camera, film) = ctx.sensor(s)?;
            Ok(FileView { camera: Some(camera), film: Some(film) })
        }
        None => Ok(FileView::default()),
    }
}

/// Loads a Mitsuba 3 XML scene; `files` are the scene's files (main first).
pub fn load(main: &NamedBytes, files: &[NamedBytes], progress: &dyn Progress) -> Result<Scene, SceneError> {
    let doc = parse_document(&main.name, &main.data)?;
    let ctx = Ctx::new(&main.name, &doc, files)?;
    let root = doc.root_element();
    let camera = match ctx.find_sensor(None)? {
        Some(s) => Some(ctx.sensor(s)?.0),
        None => None,
    };
    let mut objects = Vec::new();
    let mut lights: Vec<Light> = Vec::new();
    let mut ambient = Vec3::ZERO;
    // Directional lights are placed once every shape is known (they sit outside them all).
    let mut directional: Vec<(Vec3, Vec3)> = Vec::new();
    let mut shape_count = 0;
    let mut meshes: HashMap<String, Arc<Mesh>> = HashMap::new();
    for n in root.children().filter(|n| n.is_element()) {
        match n.tag_name().name() {
            "default" | "bsdf" | "texture" | "spectrum" | "rgb" | "sensor" => {}
            "integrator" => tracing::info!(
                "{}:{}: integrator `{}` ignored: edgepoint shades with its own shaders (--shader)",
                ctx.name,
                ctx.line(n),
                n.attribute("type").unwrap_or("")
            ),
            "shape" => {
                let ty = ctx.need(n, "type")?;
                shape_count += 1;
                let Some((mesh, pre)) = ctx.shape_mesh(n, &ty, &mut meshes, progress)? else { continue };
                let m = ctx.to_world(n)? * pre;
                let transform = affine(&m);
                crate::limits::check_affine(&transform).map_err(|e| ctx.err(n, format!("to_world: {e}")))?;
                let mut material = ctx.shape_material(n)?;
                if let Some(e) = n.children().find(|c| c.has_tag_name("emitter")) {
                    let ety = ctx.need(e, "type")?;
                    if ety != "area" {
                        ctx.warn(e, format!("emitter `{ety}` on a shape is not supported: treated as an area emitter"));
                    }
                    let radiance = ctx.emitted(e, "radiance")?;
                    if ty == "sphere" {
                        // A curved emitter would be one light per facet: the nearest light is
                        // a point at the centre with the same power (Φ = L π · 4π r²).
                        let r = m.transform_vector3(DVec3::X).length() as f32;
                        let position = m.transform_point3(DVec3::ZERO).as_vec3();
                        ctx.warn(e, "an emitting sphere is approximated by a point light of the same power at its centre");
                        lights.push(Light::Point { position, intensity: radiance * std::f32::consts::PI * r * r });
                    } else {
                        let world: Vec<[Vec3; 3]> = (0..mesh.triangles.len()).map(|f| mesh.triangle(f).map(|p| transform.transform_point3(p))).collect();
                        let what = format!("{}:{}", ctx.name, ctx.line(n));
                        let made = area_lights(&what, &world, radiance);
                        if made.len() > 64 {
                            ctx.warn(e, format!("this emitter makes {} area lights (one per flat convex patch), each costing shadow rays per sample", made.len()));
                        }
                        lights.extend(made);
                    }
                    material.emission = radiance;
                }
                let name = match (ctx.attr(n, "id")?, ctx.string(n, "filename")?) {
                    (Some(id), _) => id,
                    (None, Some(f)) => super::stem(&f),
                    (None, None) => format!("{ty} {shape_count}"),
                };
                objects.push(Object { name, mesh, material, transform });
            }
            "emitter" => {
                let ty = ctx.need(n, "type")?;
                match ty.as_str() {
                    "point" => {
                        let m = ctx.to_world(n)?;
                        let position = ctx.point(n, "position", m.transform_point3(DVec3::ZERO))?.as_vec3();
                        lights.push(Light::Point { position, intensity: ctx.emitted(n, "intensity")? });
                    }
                    "spot" => {
                        let m = ctx.to_world(n)?;
                        let cutoff = ctx.float(n, "cutoff_angle", 20.0)?;
                        let beam = ctx.float(n, "beam_width", cutoff * 0.75)?.min(cutoff);
                        lights.push(Light::Spot {
                            position: m.transform_point3(DVec3::ZERO).as_vec3(),
                            direction: m.transform_vector3(DVec3::Z).normalize_or_zero().as_vec3(),
                            intensity: ctx.emitted(n, "intensity")?,
                            cos_inner: beam.to_radians().cos() as f32,
                            cos_outer: cutoff.to_radians().cos() as f32,
                        });
                    }
                    "directional" => {
                        let m = ctx.to_world(n)?;
                        let dir = match ctx.prop(n, "direction") {
                            Some(p) => ctx.xyz(p, 0.0)?,
                            None => m.transform_vector3(DVec3::Z),
                        };
                        let irradiance = ctx.emitted(n, "irradiance")?;
                        ctx.warn(n, "directional emitter: approximated by a point light far away in its direction (edgepoint has no lights at infinity)");
                        directional.push((dir.as_vec3(), irradiance));
                    }
                    "constant" => {
                        ambient = ctx.emitted(n, "radiance")?;
                        ctx.warn(n, format!("constant environment emitter: approximated by the ambient term ({ambient}, unshadowed)"));
                    }
                    other => ctx.warn(n, format!("emitter `{other}` is not supported: ignored (supported: area on shapes, point, spot; directional and constant approximated)")),
                }
            }
            other => ctx.warn(n, format!("<{other}> is not supported: ignored")),
        }
    }
    if objects.is_empty() {
        return Err(SceneError::file(&main.name, "the scene has no (supported) shapes"));
    }
    for (dir, irradiance) in directional {
        lights.push(distant_light(dir, irradiance, &objects));
    }
    let mut scene = stage_meshes(&super::stem(&main.name), objects, lights, camera);
    if ambient != Vec3::ZERO {
        scene.ambient = ambient;
    }
    Ok(scene)
}

/// A directional light (unit `direction` of travel, `irradiance`) as a point light 10⁴
/// scene radii up-light of the scene's centre: its rays are within 10⁻⁴ rad of parallel
/// across the scene, and its irradiance at the centre is `irradiance`.
pub(crate) fn distant_light(direction: Vec3, irradiance: Vec3, objects: &[Object]) -> Light {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for o in objects {
        let (a, b) = crate::geometry::transformed_box(&o.transform, o.mesh.bounds);
        lo = lo.min(a);
        hi = hi.max(b);
    }
    let (centre, radius) = if lo.x <= hi.x { ((lo + hi) * 0.5, ((hi - lo).length() * 0.5).max(1e-3)) } else { (Vec3::ZERO, 1.0) };
    let d = radius * 1e4;
    let dir = direction.try_normalize().unwrap_or(-Vec3::Y);
    Light::Point { position: centre - dir * d, intensity: irradiance * d * d }
}
