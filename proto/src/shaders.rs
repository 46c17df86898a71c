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
}

/// The shader an empty `start.shader` means.
pub const DEFAULT_SHADER: &str = "direct";

/// Every shader.
pub const SHADERS: &[ShaderInfo] = &[ShaderInfo {
    name: "direct",
    help: "point and polygonal area lights with shadow rays, Lambertian, ambient (paper 000)",
    params: &[
        ShaderParam {
            name: "shadow_rays",
            min: 1.0,
            max: 4096.0,
            default: 16.0,
            integer: true,
            help: "shadow rays per area light per sample (stratified)",
        },
        ShaderParam { name: "ambient", min: 0.0, max: 100.0, default: 1.0, integer: false, help: "scale of the scene's ambient term (built-ins: their own; a bare model staged by the loader: 0.03 grey; a scene file that brings its own lights or camera: none, so 0 whatever the scale)" },
    ],
}];

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
        assert!(resolve("glossy", &HashMap::new()).unwrap_err().contains("shaders: direct"));
        // Every row is consistent: the default is valid.
        for s in SHADERS {
            for p in s.params {
                assert!(p.min <= p.default && p.default <= p.max && (!p.integer || p.default.fract() == 0.0), "{}", p.name);
            }
        }
        let h = help_text();
        assert!(h.contains("direct:") && h.contains("shadow_rays (whole number 1..=4096, default 16)"), "{h}");
    }
}
