//! Split shading on the renderer's side (paper 004 §4.4, "Compositing ... involves just an
//! additive blending"): the parts of one sample arrive from any workers in any order, and
//! the sample enters the Render Cache only once every part has arrived, with the parts'
//! radiance added. A partial sum is never cached: a part that a dead worker took with it is
//! shaded again by another worker (the dispatcher re-queues a failed worker's batches), and
//! a sample whose part is given up for good (its epoch can no longer be shaded) is forgotten
//! with its request ([`PartSums::forget`]).
//!
//! Radiance is summed in f64: the parts of an f32 radiance add up to the same value in any
//! arrival order, so a split sample does not depend on which worker answered first.
use edgepoint_proto as pb;
use edgepoint_proto::split::MAX_PARTS;
use glam::DVec3;
use std::collections::HashMap;

/// The parts of one sample received so far.
#[derive(Debug, Clone)]
struct Pending {
    /// Bit `i`: part `i` has arrived.
    got: u64,
    rgb: DVec3,
    /// The first part's sample (hit, position, normals: the same ray gives every part the
    /// same hit).
    first: pb::Sample,
    epoch: u64,
}

/// What one arriving part made of its sample.
#[derive(Debug, Clone, PartialEq)]
pub enum PartOutcome {
    /// The last part arrived: the whole sample (radiance summed) and its batch epoch.
    Complete(pb::Sample, u64),
    /// More parts are on their way.
    Waiting,
    /// A part already received (a re-shaded batch answered twice): ignored.
    Duplicate,
    /// Not a part of this split (index out of range), or its hit disagrees with the other
    /// parts' (the same ray at the same epoch cannot): the sample is dropped.
    Mismatch,
}

/// Sums the parts of split samples by request id.
#[derive(Debug)]
pub struct PartSums {
    parts: u32,
    all: u64,
    pending: HashMap<u64, Pending>,
}

impl PartSums {
    /// Sums of samples split into `parts` (1..=64; 1 passes every sample straight through).
    pub fn new(parts: u32) -> PartSums {
        assert!((1..=MAX_PARTS).contains(&parts), "parts {parts} outside 1..={MAX_PARTS} (checked at start)");
        let all = if parts == 64 { u64::MAX } else { (1u64 << parts) - 1 };
        PartSums { parts, all, pending: HashMap::new() }
    }

    pub fn parts(&self) -> u32 {
        self.parts
    }

    /// Samples with some parts received and some not.
    pub fn waiting(&self) -> usize {
        self.pending.len()
    }

    /// Bytes of the pending sums (for the session's memory estimate): about this much per
    /// sample waiting for parts.
    pub const BYTES_PER_PENDING: usize = std::mem::size_of::<(u64, Pending)>() + 16;

    /// Adds one arriving part (`s.part`) of a sample shaded at `epoch`.
    pub fn add(&mut self, epoch: u64, s: &pb::Sample) -> PartOutcome {
        if self.parts == 1 {
            return if s.part == 0 { PartOutcome::Complete(*s, epoch) } else { PartOutcome::Mismatch };
        }
        if s.part >= self.parts {
            return PartOutcome::Mismatch;
        }
        let bit = 1u64 << s.part;
        let rgb = pb::vec3_or_zero(&s.rgb).as_dvec3();
        let p = match self.pending.entry(s.id) {
            std::collections::hash_map::Entry::Vacant(v) => {
                v.insert(Pending { got: bit, rgb, first: *s, epoch });
                return PartOutcome::Waiting;
            }
            std::collections::hash_map::Entry::Occupied(o) => o.into_mut(),
        };
        if p.got & bit != 0 {
            return PartOutcome::Duplicate;
        }
        let f = &p.first;
        if f.hit != s.hit || f.object_id != s.object_id || f.triangle != s.triangle || p.epoch != epoch {
            self.pending.remove(&s.id);
            return PartOutcome::Mismatch;
        }
        p.got |= bit;
        p.rgb += rgb;
        if p.got != self.all {
            return PartOutcome::Waiting;
        }
        let p = self.pending.remove(&s.id).expect("present");
        let mut whole = p.first;
        whole.rgb = Some(p.rgb.as_vec3().into());
        whole.part = 0;
        PartOutcome::Complete(whole, p.epoch)
    }

    /// Forgets the samples whose request `remembered` no longer knows (the session's request
    /// ring reused its slot, or a part was given up); returns how many. Keeps the sums
    /// bounded by the requests the session remembers.
    pub fn forget(&mut self, remembered: impl Fn(u64) -> bool) -> usize {
        let before = self.pending.len();
        self.pending.retain(|&id, _| remembered(id));
        before - self.pending.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn part(id: u64, part: u32, rgb: Vec3) -> pb::Sample {
        pb::Sample { id, part, hit: true, object_id: 2, triangle: 5, rgb: Some(rgb.into()), position: Some(Vec3::ONE.into()), ..Default::default() }
    }

    #[test]
    fn a_sample_completes_only_with_every_part_in_any_order() {
        let mut sums = PartSums::new(3);
        let vals = [Vec3::new(0.1, 0.2, 0.3), Vec3::new(1.0, 0.0, 0.5), Vec3::new(1e-7, 3.0, 0.25)];
        let want = vals[0] + vals[1] + vals[2];
        for order in [[0, 1, 2], [2, 0, 1], [1, 2, 0]] {
            let mut out = Vec::new();
            for &i in &order {
                out.push(sums.add(4, &part(9, i, vals[i as usize])));
            }
            assert_eq!(out[0], PartOutcome::Waiting);
            assert_eq!(out[1], PartOutcome::Waiting);
            let PartOutcome::Complete(s, epoch) = &out[2] else { panic!("{out:?}") };
            assert_eq!(epoch, &4);
            assert_eq!((s.id, s.part, s.object_id, s.triangle), (9, 0, 2, 5));
            let got = pb::vec3_or_zero(&s.rgb);
            assert!((got - want).abs().max_element() < 1e-6, "{got} vs {want}");
            assert_eq!(sums.waiting(), 0);
        }
    }

    #[test]
    fn duplicates_mismatches_and_forgotten_requests_never_complete() {
        let mut sums = PartSums::new(2);
        assert_eq!(sums.add(0, &part(1, 0, Vec3::ONE)), PartOutcome::Waiting);
        assert_eq!(sums.add(0, &part(1, 0, Vec3::ONE)), PartOutcome::Duplicate);
        assert_eq!(sums.add(0, &part(1, 2, Vec3::ONE)), PartOutcome::Mismatch, "part 2 of 2");
        let mut other = part(1, 1, Vec3::ONE);
        other.object_id = 3;
        assert_eq!(sums.add(0, &other), PartOutcome::Mismatch, "another hit");
        assert_eq!(sums.waiting(), 0, "the disagreeing sample is dropped");
        assert_eq!(sums.add(0, &part(2, 1, Vec3::ONE)), PartOutcome::Waiting);
        assert_eq!(sums.add(1, &part(2, 0, Vec3::ONE)), PartOutcome::Mismatch, "another epoch");
        assert_eq!(sums.add(0, &part(5, 1, Vec3::ONE)), PartOutcome::Waiting);
        assert_eq!(sums.add(0, &part(6, 0, Vec3::ONE)), PartOutcome::Waiting);
        assert_eq!(sums.forget(|id| id >= 6), 1);
        assert_eq!(sums.waiting(), 1);
        assert_eq!(sums.add(0, &part(5, 0, Vec3::ONE)), PartOutcome::Waiting, "forgotten: starts again, never completes from the lost half");
    }

    #[test]
    fn unsplit_samples_pass_through_and_sixty_four_parts_fit() {
        let mut one = PartSums::new(1);
        let s = part(3, 0, Vec3::X);
        assert_eq!(one.add(7, &s), PartOutcome::Complete(s, 7));
        let mut many = PartSums::new(64);
        for i in 0..63 {
            assert_eq!(many.add(0, &part(1, i, Vec3::splat(1.0))), PartOutcome::Waiting);
        }
        let PartOutcome::Complete(s, _) = many.add(0, &part(1, 63, Vec3::splat(1.0))) else { panic!() };
        assert_eq!(pb::vec3_or_zero(&s.rgb), Vec3::splat(64.0));
    }
}
