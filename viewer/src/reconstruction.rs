//! Command-line switches for the server's reconstruction settings (edge-and-point image vs
//! the Render Cache baseline, complex filter, overlays, sharp-edge cut-off), shared by the
//! viewer and `edgepoint-bench frame`.
use clap::ValueEnum;
use edgepoint_proto as pb;

/// How the server reconstructs frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ReconstructionMode {
    /// The edge-and-point image: edge-respecting interpolation, anti-aliasing, complex filter
    /// (paper 000 §4–5). The server's default.
    Epr,
    /// The baseline: Render Cache interpolation from the same samples, ignoring edges.
    RenderCache,
}

impl ReconstructionMode {
    pub fn to_wire(self) -> pb::Reconstruction {
        match self {
            ReconstructionMode::Epr => pb::Reconstruction::EdgeAndPoint,
            ReconstructionMode::RenderCache => pb::Reconstruction::RenderCache,
        }
    }

    /// The name on the command line and in stats.
    pub fn name(self) -> &'static str {
        reconstruction_name(self.to_wire() as i32)
    }
}

/// A diagnostic overlay drawn over the frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum OverlayMode {
    /// No overlay.
    None,
    /// Pixels crossed by rasterized edges (simple yellow, complex orange).
    Edges,
    /// Pixel classes as in paper Fig. 7: simple purple, complex green.
    Classes,
    /// Pixels holding a sample: usable white, edge-ambiguous red, in complex pixels orange.
    Samples,
}

/// The reconstruction switches.
#[derive(clap::Args, Debug, Clone, Default, PartialEq)]
pub struct ReconstructionArgs {
    /// How the server reconstructs frames: `epr` (edge-and-point rendering, the default) or
    /// `render-cache` (the baseline interpolation, which ignores edges).
    #[arg(long, value_enum, value_name = "MODE")]
    pub reconstruction: Option<ReconstructionMode>,

    /// Turn off the complex-pixel filter (paper §5.4); complex pixels then show their
    /// unconstrained interpolation.
    #[arg(long)]
    pub no_complex_filter: bool,

    /// Draw a diagnostic overlay of the edge-and-point image over the frames.
    #[arg(long, value_enum, value_name = "KIND")]
    pub overlay: Option<OverlayMode>,

    /// Sharp-edge cut-off in degrees, (0, 180]: forward-facing edges whose faces meet at
    /// this angle or more are discontinuities (server default 85).
    #[arg(long, value_name = "DEG", allow_negative_numbers = true, value_parser = parse_cutoff)]
    pub sharp_cutoff: Option<f64>,

    /// Several lights (paper 003): leave out the shadow edges other lights wash out, those
    /// whose estimated relative L2 error of leaving them out is below T (e.g. 0.05); 0 keeps
    /// every shadow edge (server default: its --simplify-tolerance, normally 0).
    #[arg(long, value_name = "T", value_parser = parse_tolerance)]
    pub simplify_tolerance: Option<f64>,

    /// Where area lights' shadow edges come from: `triples` (the renderer's edge finder,
    /// from the light–blocker–receiver triples the workers report; the server's default) or
    /// `mesh` (the discontinuity mesh of every area light, paper 002: its umbral and
    /// penumbral boundaries and the interior edges across which the irradiance's slope
    /// jumps steeply; computed on the session's shadow thread, seconds on big scenes, and
    /// updated incrementally when an object moves). Point lights' hard shadow edges come
    /// from the triples either way.
    #[arg(long, value_enum, value_name = "SOURCE")]
    pub shadow_edges: Option<ShadowEdgesMode>,
}

/// `--shadow-edges`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ShadowEdgesMode {
    Triples,
    Mesh,
}

fn parse_tolerance(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() || !(0.0..=100.0).contains(&v) {
        return Err(format!("must be in [0, 100] (0 = off), got {s}"));
    }
    Ok(v)
}

fn parse_cutoff(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() || v <= 0.0 || v > 180.0 {
        return Err(format!("must be in (0, 180] degrees, got {s}"));
    }
    Ok(v)
}

impl ReconstructionArgs {
    /// Whether any switch was given.
    pub fn is_set(&self) -> bool {
        *self != ReconstructionArgs::default()
    }

    /// Writes the switches given into `s` (the others keep the server's values).
    pub fn apply(&self, s: &mut pb::Settings) {
        if let Some(m) = self.reconstruction {
            s.reconstruction = m.to_wire() as i32;
        }
        if self.no_complex_filter {
            s.complex_filter = Some(false);
        }
        if let Some(o) = self.overlay {
            s.overlay = match o {
                OverlayMode::None => pb::Overlay::None,
                OverlayMode::Edges => pb::Overlay::Edges,
                OverlayMode::Classes => pb::Overlay::Classes,
                OverlayMode::Samples => pb::Overlay::Samples,
            } as i32;
        }
        if let Some(c) = self.sharp_cutoff {
            s.sharp_cutoff_degrees = c;
        }
        if let Some(t) = self.simplify_tolerance {
            s.simplify_tolerance = Some(t);
        }
        if let Some(m) = self.shadow_edges {
            s.shadow_edges = match m {
                ShadowEdgesMode::Triples => pb::ShadowEdges::Triples,
                ShadowEdgesMode::Mesh => pb::ShadowEdges::Mesh,
            } as i32;
        }
    }
}

/// Name of a wire reconstruction mode (for stats).
pub fn reconstruction_name(r: i32) -> &'static str {
    match pb::Reconstruction::try_from(r) {
        Ok(pb::Reconstruction::EdgeAndPoint) => "epr",
        Ok(pb::Reconstruction::RenderCache) => "render-cache",
        _ => "unspecified",
    }
}

/// Name of a wire overlay (for stats and the window's status line).
pub fn overlay_name(o: i32) -> &'static str {
    match pb::Overlay::try_from(o) {
        Ok(pb::Overlay::None) => "none",
        Ok(pb::Overlay::Edges) => "edges",
        Ok(pb::Overlay::Classes) => "classes",
        Ok(pb::Overlay::Samples) => "samples",
        _ => "unspecified",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        r: ReconstructionArgs,
    }

    #[test]
    fn switches_become_settings() {
        let none = Cli::parse_from(["x"]).r;
        assert!(!none.is_set());
        let mut s = pb::Settings::default();
        none.apply(&mut s);
        assert_eq!(s, pb::Settings::default());
        let all = Cli::parse_from(["x", "--reconstruction", "render-cache", "--no-complex-filter", "--overlay", "classes", "--sharp-cutoff", "40"]).r;
        assert!(all.is_set());
        all.apply(&mut s);
        assert_eq!(s.reconstruction, pb::Reconstruction::RenderCache as i32);
        assert_eq!((s.complex_filter, s.overlay, s.sharp_cutoff_degrees), (Some(false), pb::Overlay::Classes as i32, 40.0));
        assert!(Cli::try_parse_from(["x", "--sharp-cutoff", "0"]).is_err());
        assert!(Cli::try_parse_from(["x", "--sharp-cutoff", "200"]).is_err());
        assert!(Cli::try_parse_from(["x", "--reconstruction", "magic"]).is_err());
        let m = Cli::parse_from(["x", "--shadow-edges", "mesh"]).r;
        let mut s = pb::Settings::default();
        m.apply(&mut s);
        assert_eq!(s.shadow_edges, pb::ShadowEdges::Mesh as i32);
        assert!(Cli::try_parse_from(["x", "--shadow-edges", "sometimes"]).is_err());
        let t = Cli::parse_from(["x", "--simplify-tolerance", "0.05"]).r;
        assert!(t.is_set());
        let mut s = pb::Settings::default();
        t.apply(&mut s);
        assert_eq!(s.simplify_tolerance, Some(0.05));
        assert!(Cli::try_parse_from(["x", "--simplify-tolerance", "-1"]).is_err());
        assert!(Cli::try_parse_from(["x", "--simplify-tolerance", "nan"]).is_err());
        assert_eq!(reconstruction_name(1), "epr");
        assert_eq!((overlay_name(2), overlay_name(1), overlay_name(99)), ("edges", "none", "unspecified"));
    }
}
