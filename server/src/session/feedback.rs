//! What the shader reports besides colours (paper 000 §3: "the shader also sends information
//! to the edge finder about currently visible objects and shadows"; §6.5): the objects the
//! primary rays hit, and light–blocker–receiver triples from blocked shadow rays. The session
//! accumulates them with counts; the edge finder decides from them which objects need
//! silhouettes and which (blocker, receiver) pairs need shadow edges.
use edgepoint_proto::SampleBatch;
use std::collections::HashMap;

// The edge finder's key (it lives with the algorithm, which the session feeds).
pub use crate::edges::TripleKey;

/// Accumulated shading feedback of one session.
#[derive(Debug, Clone, Default)]
pub struct ShadingFeedback {
    /// Times each triple was reported, and the last epoch it was reported at.
    pub triples: HashMap<TripleKey, TripleSeen>,
    /// Per object id: batches whose primary rays hit it, and the last epoch it was seen.
    pub visible: Vec<ObjectSeen>,
    /// Samples the workers reported as non-finite (clamped by the worker).
    pub nonfinite: u64,
    /// Reports naming an object id the scene does not have (ignored).
    pub bad_ids: u64,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TripleSeen {
    pub count: u64,
    pub last_epoch: u64,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ObjectSeen {
    pub batches: u64,
    pub last_epoch: u64,
}

impl ShadingFeedback {
    pub fn new(objects: usize) -> Self {
        ShadingFeedback { visible: vec![ObjectSeen::default(); objects], ..Default::default() }
    }

    /// Adds one answered batch's reports.
    pub fn record(&mut self, b: &SampleBatch, lights: usize) {
        let objects = self.visible.len() as u32;
        for &o in &b.visible_objects {
            match self.visible.get_mut(o as usize) {
                Some(v) => {
                    v.batches += 1;
                    v.last_epoch = v.last_epoch.max(b.epoch);
                }
                None => self.bad_ids += 1,
            }
        }
        for t in &b.triples {
            if t.blocker >= objects || t.receiver >= objects || t.light as usize >= lights {
                self.bad_ids += 1;
                continue;
            }
            let e = self.triples.entry(TripleKey { light: t.light, blocker: t.blocker, receiver: t.receiver }).or_default();
            e.count += 1;
            e.last_epoch = e.last_epoch.max(b.epoch);
        }
        self.nonfinite += b.nonfinite as u64;
    }

    /// Objects seen by primary rays at `epoch` or later.
    pub fn visible_since(&self, epoch: u64) -> impl Iterator<Item = u32> + '_ {
        self.visible.iter().enumerate().filter(move |(_, v)| v.batches > 0 && v.last_epoch >= epoch).map(|(i, _)| i as u32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgepoint_proto::Triple;

    #[test]
    fn counts_triples_and_visibility_and_ignores_bad_ids() {
        let mut f = ShadingFeedback::new(3);
        let b = SampleBatch {
            epoch: 2,
            visible_objects: vec![0, 2, 9],
            triples: vec![
                Triple { light: 0, blocker: 1, receiver: 0 },
                Triple { light: 0, blocker: 1, receiver: 0 },
                Triple { light: 1, blocker: 2, receiver: 0 },
                Triple { light: 0, blocker: 7, receiver: 0 },
            ],
            nonfinite: 2,
            ..Default::default()
        };
        f.record(&b, 1);
        assert_eq!(f.triples.len(), 1);
        assert_eq!(f.triples[&TripleKey { light: 0, blocker: 1, receiver: 0 }], TripleSeen { count: 2, last_epoch: 2 });
        assert_eq!(f.bad_ids, 3, "object 9, light 1 and blocker 7 do not exist");
        assert_eq!(f.nonfinite, 2);
        assert_eq!(f.visible_since(0).collect::<Vec<_>>(), vec![0, 2]);
        assert_eq!(f.visible_since(3).count(), 0);
    }
}
