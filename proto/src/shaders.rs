//! The one table of shaders and their parameters (name, valid range, default, one line of
//! help). The worker parses batches with it, the server checks a session's `start` against
//! it (so a bad parameter is refused with INVALID_ARGUMENT listing the valid ones, instead
//! of a session of black frames), and `--help` texts print it. A new shader (glossy, gi,
//! hybrid) adds its row here and its module in the worker.
use std::collections::HashMap;

/// One numeric shader parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShaderParam {
    pub name: &'static str,
    /// Valid range, inclusive.
    pub min: f64,
    pub max: f64,
    pub default: f64,
    /// Only whole numbers are valid.
    pub integer: bool,
    pub help: &'static str,
}

/// A shader and its parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShaderInfo {
    pub name: &'static str,
    pub help: &'static str,
    pub params: &'static [ShaderParam],
    /// Raised whenever a change alters the images the shader makes with the same
    /// parameters (a fix, a new estimator): cached converged references carry it in their
    /// key, so a reference rendered before the change is not compared with images after it.
    pub revision: u32,
}

/// The shader an empty `start.shader` means.
pub const DEFAULT_SHADER: &str = "direct";

/// `shadow_rays` and `ambient` as `direct` has them (shared by `direct` and `glossy`).
const SHADOW_RAYS: ShaderParam = ShaderParam {
    name: "shadow_rays",
    min: 1.0,
    max: 4096.0,
    default: 16.0,
    integer: true,
    help: "shadow rays per area light per sample (stratified)",
};
const AMBIENT: ShaderParam = ShaderParam { name: "ambient", min: 0.0, max: 100.0, default: 1.0, integer: false, help: "scale of the scene's ambient term (built-ins: their own; a bare model staged by the loader: 0.03 grey; a scene file that brings its own lights or camera: none, so 0 whatever the scale)" };

/// How `direct` lights a point from an area light (`area`): 0 `sampled`, `shadow_rays`
/// stratified rays (noisy soft shadows); 1 `exact`, the visible part of the light clipped
/// from the blockers in the point–light pyramid and Lambert's formula over it (no noise).
const AREA: ShaderParam = ShaderParam {
    name: "area",
    min: 0.0,
    max: 1.0,
    default: 0.0,
    integer: true,
    help: "area lights: 0 or `sampled` = shadow_rays stratified rays; 1 or `exact` = the exact visible part of the light (blockers clipped in the point-light pyramid) and Lambert's closed form: soft shadows without noise, cost grows with the blockers in the pyramid",
};

/// Parameters whose values have names too (`--shader-param area=exact`): the name stands
/// for its number, which is what travels in `start`.
pub const VALUE_NAMES: &[(&str, &[(&str, f64)])] = &[("area", &[("sampled", 0.0), ("exact", 1.0)])];

/// Parses a `--shader-param KEY=VALUE`: VALUE a finite number or one of the key's names
/// ([`VALUE_NAMES`]). The range is checked later, against the shader ([`resolve`]).
pub fn parse_param(s: &str) -> Result<(String, f64), String> {
    let (k, v) = s.split_once('=').ok_or_else(|| format!("expected KEY=VALUE, got '{s}'"))?;
    let (k, v) = (k.trim(), v.trim());
    if k.is_empty() {
        return Err(format!("empty parameter name in '{s}'"));
    }
    let names = VALUE_NAMES.iter().find(|(key, _)| *key == k).map_or(&[][..], |(_, n)| *n);
    if let Some((_, x)) = names.iter().find(|(name, _)| *name == v) {
        return Ok((k.to_string(), *x));
    }
    let x: f64 = v.parse().map_err(|_| {
        let named = names.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", ");
        format!("value of '{k}' must be a number{}, got '{v}'", if named.is_empty() { String::new() } else { format!(" or one of {named}") })
    })?;
    if !x.is_finite() {
        return Err(format!("value of '{k}' must be finite, got {x}"));
    }
    Ok((k.to_string(), x))
}

/// Every shader.
pub const SHADERS: &[ShaderInfo] = &[
    ShaderInfo {
        name: "direct",
        help: "point and polygonal area lights with shadow rays (or exact area-light visibility), Lambertian, ambient (paper 000)",
        params: &[SHADOW_RAYS, AMBIENT, AREA],
        revision: 1,
    },
    ShaderInfo {
        name: "glossy",
        help: "direct light and ambient as `direct`, plus glossy and mirror reflection (and refraction) traced by sampling the non-diffuse part of the BSDF (paper 000 §7's second shader)",
        params: &[
            SHADOW_RAYS,
            AMBIENT,
            ShaderParam { name: "rays", min: 1.0, max: 256.0, default: 4.0, integer: true, help: "BSDF-sampled reflection rays K at the first hit (one per deeper hit)" },
            ShaderParam { name: "max_depth", min: 1.0, max: 16.0, default: 3.0, integer: true, help: "reflection bounces followed (1: reflections show direct light and ambient only)" },
        ],
        revision: 1,
    },
    ShaderInfo {
        name: "gi",
        help: "path tracing: next-event estimation with multiple importance sampling over lights and BSDF, Russian roulette; the diffuse indirect term of Lambertian first hits from a per-worker irradiance cache (Ward records with gradients, paper 000 §7)",
        params: &[
            ShaderParam { name: "shadow_rays", min: 1.0, max: 4096.0, default: 4.0, integer: true, help: "light samples per area light at the first hit (one at deeper hits)" },
            ShaderParam { name: "max_depth", min: 1.0, max: 64.0, default: 6.0, integer: true, help: "path vertices shaded (1: direct light only); Russian roulette from the fourth" },
            ShaderParam { name: "cache", min: 0.0, max: 1.0, default: 1.0, integer: true, help: "1: irradiance cache for the diffuse indirect term of Lambertian first hits; 0: path-trace it" },
            ShaderParam { name: "cache_error", min: 0.02, max: 1.0, default: 0.15, integer: false, help: "Ward's accuracy a: a record serves points of weight above 1/a (smaller: more records, less blur)" },
            ShaderParam { name: "cache_rays", min: 16.0, max: 4096.0, default: 256.0, integer: true, help: "hemisphere rays per irradiance record (M x N strata, N ~ pi M)" },
            ShaderParam { name: "cache_max_rays", min: 16.0, max: 65536.0, default: 1024.0, integer: true, help: "rays a record grows to while it is used: once it has served a quarter as many lookups as it holds rays, it gathers cache_rays more (a still view's records lose their noise as its samples accumulate); at most cache_rays: no refinement" },
        ],
        // 2: the irradiance cache's gradients bounded (records along creases made fireflies).
        // 3: records refined while they are used (`cache_max_rays`).
        revision: 3,
    },
    ShaderInfo {
        name: "hybrid",
        help: "paper 004: soft shadows from area-light samples, one-bounce indirect light from the K virtual point lights that reflect the most light (equal-area surface elements ranked by reflected flux; built once per scene, object placement and parameters on each worker), ray-traced specular reflection and refraction; no ambient term",
        params: &[
            SHADOW_RAYS,
            ShaderParam { name: "vpls", min: 0.0, max: 4096.0, default: 64.0, integer: true, help: "virtual point lights K: the surface elements reflecting the most light, one shadow ray each per shaded surface (0: no indirect light)" },
            ShaderParam { name: "elements", min: 16.0, max: 65536.0, default: 4096.0, integer: true, help: "equal-area surface elements the VPLs are chosen from (about this many over the scene's diffuse surfaces; each costs 16 shadow rays per light when the VPLs are built)" },
            ShaderParam { name: "max_depth", min: 0.0, max: 16.0, default: 5.0, integer: true, help: "specular bounces traced (mirror reflection; glass splits into reflection and refraction); 0: delta surfaces show no scene" },
            ShaderParam { name: "conserve", min: 0.0, max: 1.0, default: 1.0, integer: true, help: "1: the K VPLs share the reflected flux of every lit element in proportion to their own (the paper's intensities proportional to the weights; no indirect energy lost); 0: each carries its own element's flux (exact one bounce when K covers every lit element)" },
        ],
        revision: 1,
    },
];

/// The shader called `name` (`""` is [`DEFAULT_SHADER`]).
pub fn shader(name: &str) -> Option<&'static ShaderInfo> {
    let name = if name.is_empty() { DEFAULT_SHADER } else { name };
    SHADERS.iter().find(|s| s.name == name)
}

fn range(p: &ShaderParam) -> String {
    format!("{}{}..={}, default {}", if p.integer { "whole number " } else { "" }, p.min, p.max, p.default)
}

/// `shadow_rays (whole number 1..=4096, default 16), ambient (0..=100, default 1)`.
pub fn param_list(s: &ShaderInfo) -> String {
    if s.params.is_empty() {
        return "none".into();
    }
    s.params.iter().map(|p| format!("{} ({})", p.name, range(p))).collect::<Vec<_>>().join(", ")
}

/// Every parameter of `shader` with `given` applied over the defaults, or why `given` is
/// refused: an unknown shader or parameter, or a value out of range. The error lists what
/// is valid.
pub fn resolve(shader_name: &str, given: &HashMap<String, f64>) -> Result<HashMap<&'static str, f64>, String> {
    let s = shader(shader_name).ok_or_else(|| {
        format!("unknown shader '{shader_name}' (shaders: {})", SHADERS.iter().map(|s| s.name).collect::<Vec<_>>().join(", "))
    })?;
    let mut out: HashMap<&'static str, f64> = s.params.iter().map(|p| (p.name, p.default)).collect();
    // Sorted, so the first error reported does not depend on hash order.
    let mut keys: Vec<&String> = given.keys().collect();
    keys.sort();
    for k in keys {
        let v = given[k];
        let p = s.params.iter().find(|p| p.name == k).ok_or_else(|| {
            format!("shader {} has no parameter '{k}' (parameters: {})", s.name, param_list(s))
        })?;
        if !(v.is_finite() && v >= p.min && v <= p.max && (!p.integer || v.fract() == 0.0)) {
            return Err(format!("shader {}: {} must be a {} , got {v}", s.name, p.name, range(p)).replace(" ,", ","));
        }
        out.insert(p.name, v);
    }
    Ok(out)
}

/// The table as `--help` text: one line per shader, one indented line per parameter.
pub fn help_text() -> String {
    let mut t = String::from("Shaders and their parameters (--shader-param KEY=VALUE):");
    for s in SHADERS {
        t.push_str(&format!("\n  {}: {}", s.name, s.help));
        for p in s.params {
            t.push_str(&format!("\n    {} ({}): {}", p.name, range(p), p.help));
        }
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn given(kv: &[(&str, f64)]) -> HashMap<String, f64> {
        kv.iter().map(|(k, v)| (k.to_string(), *v)).collect()
    }

    #[test]
    fn parameters_resolve_over_defaults_and_errors_list_the_valid_ones() {
        let d = resolve("", &HashMap::new()).unwrap();
        assert_eq!((d["shadow_rays"], d["ambient"]), (16.0, 1.0));
        let r = resolve("direct", &given(&[("shadow_rays", 4.0)])).unwrap();
        assert_eq!((r["shadow_rays"], r["ambient"]), (4.0, 1.0));
        let e = resolve("direct", &given(&[("bogus", 1.0)])).unwrap_err();
        assert!(e.contains("'bogus'") && e.contains("shadow_rays (whole number 1..=4096, default 16)") && e.contains("ambient"), "{e}");
        for bad in [("shadow_rays", 0.0), ("shadow_rays", 2.5), ("shadow_rays", f64::NAN), ("ambient", 101.0), ("ambient", -1.0)] {
            let e = resolve("direct", &given(&[bad])).unwrap_err();
            assert!(e.contains(bad.0) && e.contains("must be"), "{e}");
        }
        assert!(resolve("phong", &HashMap::new()).unwrap_err().contains("shaders: direct, glossy, gi"));
        let g = resolve("gi", &given(&[("max_depth", 3.0)])).unwrap();
        assert_eq!((g["max_depth"], g["cache"], g["shadow_rays"]), (3.0, 1.0, 4.0));
        for bad in [("cache", 2.0), ("cache_error", 0.0), ("max_depth", 0.0), ("cache_rays", 1e9)] {
            assert!(resolve("gi", &given(&[bad])).unwrap_err().contains(bad.0));
        }
        assert!(resolve("glossy", &given(&[("rays", 0.5)])).is_err());
        let h = resolve("hybrid", &given(&[("vpls", 0.0)])).unwrap();
        assert_eq!((h["vpls"], h["elements"], h["max_depth"], h["shadow_rays"]), (0.0, 4096.0, 5.0, 16.0));
        for bad in [("vpls", 4097.0), ("vpls", -1.0), ("elements", 8.0), ("elements", 1e6), ("max_depth", 17.0), ("max_depth", 1.5), ("ambient", 1.0)] {
            assert!(resolve("hybrid", &given(&[bad])).unwrap_err().contains(bad.0));
        }
        // Every row is consistent: the default is valid.
        for s in SHADERS {
            for p in s.params {
                assert!(p.min <= p.default && p.default <= p.max && (!p.integer || p.default.fract() == 0.0), "{}", p.name);
            }
        }
        let a = resolve("direct", &given(&[("area", 1.0)])).unwrap();
        assert_eq!((a["area"], d["area"]), (1.0, 0.0));
        for bad in [("area", 2.0), ("area", 0.5)] {
            assert!(resolve("direct", &given(&[bad])).unwrap_err().contains("area"));
        }
        assert!(resolve("glossy", &given(&[("area", 1.0)])).unwrap_err().contains("no parameter 'area'"));
        let h = help_text();
        assert!(h.contains("direct:") && h.contains("shadow_rays (whole number 1..=4096, default 16)"), "{h}");
    }

    #[test]
    fn command_line_values_are_numbers_or_the_keys_names() {
        assert_eq!(parse_param("area=exact").unwrap(), ("area".to_string(), 1.0));
        assert_eq!(parse_param(" area = sampled ").unwrap(), ("area".to_string(), 0.0));
        assert_eq!(parse_param("shadow_rays=16").unwrap(), ("shadow_rays".to_string(), 16.0));
        let e = parse_param("area=best").unwrap_err();
        assert!(e.contains("'area'") && e.contains("sampled, exact") && e.contains("'best'"), "{e}");
        let e = parse_param("shadow_rays=exact").unwrap_err();
        assert!(e.contains("must be a number, got 'exact'"), "{e}");
        assert!(parse_param("shadow_rays").unwrap_err().contains("KEY=VALUE"));
        assert!(parse_param("=3").unwrap_err().contains("empty parameter name"));
        assert!(parse_param("ambient=inf").unwrap_err().contains("finite"));
    }
}
