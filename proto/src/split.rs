//! Split shading (paper 004 §4.4, "Compositing": each pipe renders a partial image of some
//! of the light samples, and the partial images are added): one pixel's shading is cut into
//! parts that different workers shade at the same time, and the renderer adds the parts'
//! radiance before the sample is cached.
//!
//! The shared piece every shader uses is [`Part`]: which of a list of light sources (lights,
//! and for a shader that makes them, virtual point lights) a part shades, and whether it
//! shades the terms that belong to no light (emission, ambient, indirect and reflected
//! light: part 0 only). The rest is the wire form: the `start` option ([`SplitMode`], the
//! `--split` flag of the viewer and the bench) and the per-request `part` / `parts` fields.
use crate::v1 as pb;
use std::fmt;
use std::ops::Range;

/// Most parts a sample can be split into: the renderer tracks the parts received as bits of
/// a `u64`.
pub const MAX_PARTS: u32 = 64;

/// Part `index` of `count` of one sample's shading. `count == 1` is the whole shading.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Part {
    pub index: u32,
    pub count: u32,
}

impl Default for Part {
    fn default() -> Self {
        Part::WHOLE
    }
}

impl Part {
    /// The unsplit shading.
    pub const WHOLE: Part = Part { index: 0, count: 1 };

    /// The part a request names (`parts` 0 or 1: whole). Errors name the bad value.
    pub fn from_wire(part: u32, parts: u32) -> Result<Part, String> {
        let count = parts.max(1);
        if count > MAX_PARTS {
            return Err(format!("parts {parts} is more than {MAX_PARTS}"));
        }
        if part >= count {
            return Err(format!("part {part} of {count} (parts are numbered from 0)"));
        }
        Ok(Part { index: part, count })
    }

    pub fn is_whole(&self) -> bool {
        self.count <= 1
    }

    /// Whether this part shades the terms that belong to no light source (emission, ambient,
    /// indirect and reflected light): part 0 does, so they are counted exactly once.
    #[inline]
    pub fn shades_unsplit_terms(&self) -> bool {
        self.index == 0
    }

    /// Whether this part shades light source `i` (interleaved: `i ≡ index mod count`, so a
    /// list ordered by importance spreads its expensive head over all parts).
    #[inline]
    pub fn owns(&self, i: usize) -> bool {
        self.count <= 1 || i % self.count as usize == self.index as usize
    }

    /// The contiguous share of `n` items this part shades (the first `n mod count` parts take
    /// one more): for sources whose work is better kept together (a block of VPLs sharing
    /// one precomputation). Parts cover `0..n` exactly once.
    pub fn range(&self, n: usize) -> Range<usize> {
        let (c, i) = (self.count.max(1) as usize, self.index as usize);
        let (q, r) = (n / c, n % c);
        let start = i * q + i.min(r);
        start..start + q + usize::from(i < r)
    }
}

/// How a session spreads shading over the workers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SplitMode {
    /// Every request shades one whole pixel (the default).
    #[default]
    Pixels,
    /// Every sample is shaded in `n` parts by lights.
    Lights(u32),
}

impl SplitMode {
    /// Parts per sample (1 for [`SplitMode::Pixels`]).
    pub fn parts(&self) -> u32 {
        match self {
            SplitMode::Pixels => 1,
            SplitMode::Lights(n) => *n,
        }
    }

    /// The `start` option (`None` for pixels: older servers see what they always saw).
    pub fn to_wire(&self) -> Option<pb::Split> {
        match self {
            SplitMode::Pixels => None,
            SplitMode::Lights(n) => Some(pb::Split { by: pb::SplitBy::Lights as i32, parts: *n }),
        }
    }

    /// A `start` option checked: an unknown kind or a part count outside 2..=64 is an error
    /// naming it (1 part by lights is the same as by pixels and is accepted as such).
    pub fn from_wire(s: Option<&pb::Split>) -> Result<SplitMode, String> {
        let Some(s) = s else { return Ok(SplitMode::Pixels) };
        match pb::SplitBy::try_from(s.by) {
            Ok(pb::SplitBy::Pixels) => Ok(SplitMode::Pixels),
            Ok(pb::SplitBy::Lights) => match s.parts {
                0 => Err(format!("split by lights needs parts between 1 and {MAX_PARTS}, not 0")),
                1 => Ok(SplitMode::Pixels),
                n if n <= MAX_PARTS => Ok(SplitMode::Lights(n)),
                n => Err(format!("split by lights into {n} parts: at most {MAX_PARTS}")),
            },
            Err(_) => Err(format!("split.by {} is not a known SplitBy (0 pixels, 1 lights)", s.by)),
        }
    }
}

impl fmt::Display for SplitMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SplitMode::Pixels => write!(f, "pixels"),
            SplitMode::Lights(n) => write!(f, "lights:{n}"),
        }
    }
}

impl std::str::FromStr for SplitMode {
    type Err = String;

    /// `pixels`, or `lights:N` with N in 1..=64 (the `--split` flag).
    fn from_str(s: &str) -> Result<SplitMode, String> {
        let s = s.trim();
        if s == "pixels" || s == "none" {
            return Ok(SplitMode::Pixels);
        }
        let Some(n) = s.strip_prefix("lights:") else {
            return Err(format!("'{s}': expected 'pixels' or 'lights:N' (N parts, 1 to {MAX_PARTS})"));
        };
        let n: u32 = n.parse().map_err(|_| format!("'{s}': '{n}' is not a whole number of parts"))?;
        let wire = pb::Split { by: pb::SplitBy::Lights as i32, parts: n };
        SplitMode::from_wire(Some(&wire))
    }
}

/// Help text of the `--split` flag (viewer and bench).
pub const SPLIT_HELP: &str = "How one pixel's shading is spread over the workers (paper 004 §4.4): \
`pixels` (default: each request shades a whole pixel) or `lights:N` (each sample is shaded in N \
parts, 1-64, that any workers shade at once: part i takes the lights with index i mod N, part 0 \
also emission, ambient and indirect light; the server adds the parts before caching the sample)";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_cover_every_light_once() {
        for count in 1..=9u32 {
            for n in 0..40usize {
                let mut seen = vec![0u32; n];
                let mut ranged = vec![0u32; n];
                for index in 0..count {
                    let p = Part { index, count };
                    for (i, s) in seen.iter_mut().enumerate() {
                        *s += p.owns(i) as u32;
                    }
                    for i in p.range(n) {
                        ranged[i] += 1;
                    }
                    let len = p.range(n).len();
                    assert!(len == n / count as usize || len == n / count as usize + 1, "balanced: {len} of {n} over {count}");
                }
                assert!(seen.iter().all(|&s| s == 1), "count {count}, n {n}: {seen:?}");
                assert!(ranged.iter().all(|&s| s == 1), "count {count}, n {n}: {ranged:?}");
            }
        }
        assert_eq!((0..4).filter(|&i| Part::WHOLE.owns(i)).count(), 4);
        assert!(Part::WHOLE.shades_unsplit_terms());
        assert!(!Part { index: 1, count: 2 }.shades_unsplit_terms());
    }

    #[test]
    fn wire_values_are_checked() {
        assert_eq!(Part::from_wire(0, 0), Ok(Part::WHOLE));
        assert_eq!(Part::from_wire(0, 1), Ok(Part::WHOLE));
        assert_eq!(Part::from_wire(2, 3), Ok(Part { index: 2, count: 3 }));
        assert!(Part::from_wire(3, 3).unwrap_err().contains("part 3 of 3"));
        assert!(Part::from_wire(1, 0).is_err());
        assert!(Part::from_wire(0, 65).unwrap_err().contains("65"));
    }

    #[test]
    fn the_flag_parses_and_round_trips() {
        assert_eq!("pixels".parse(), Ok(SplitMode::Pixels));
        assert_eq!("lights:4".parse(), Ok(SplitMode::Lights(4)));
        assert_eq!("lights:1".parse(), Ok(SplitMode::Pixels));
        assert!("lights:0".parse::<SplitMode>().unwrap_err().contains("not 0"));
        assert!("lights:65".parse::<SplitMode>().unwrap_err().contains("65"));
        assert!("lights:x".parse::<SplitMode>().unwrap_err().contains("'x'"));
        assert!("vpls:2".parse::<SplitMode>().unwrap_err().contains("lights:N"));
        for m in [SplitMode::Pixels, SplitMode::Lights(3)] {
            assert_eq!(m.to_string().parse(), Ok(m));
            assert_eq!(SplitMode::from_wire(m.to_wire().as_ref()), Ok(m));
        }
        assert!(SplitMode::from_wire(Some(&pb::Split { by: 7, parts: 2 })).unwrap_err().contains("7"));
    }
}
