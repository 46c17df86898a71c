//! Scene epochs as the dispatcher knows them (DESIGN.md: every sample request carries the
//! scene epoch). Each epoch maps to the *full* set of object transforms that differ from the
//! scene defaults, so a link can bring a worker to any retained epoch with one
//! `TransformEpoch` message, whatever the worker saw before on that stream.
use edgepoint_proto::{affine_to_wire, ObjectTransform};
use glam::Affine3A;
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;

/// How many recent epochs stay sendable. Batches of older epochs that were never sent on a
/// link cannot be shaded consistently any more and are dropped.
pub const RETAINED_EPOCHS: usize = 64;

/// The full override set of one epoch, encoded once and shared by every link.
pub type EpochTransforms = Arc<Vec<ObjectTransform>>;

#[derive(Debug)]
pub struct EpochTable {
    current: u64,
    overrides: BTreeMap<u32, Affine3A>,
    history: VecDeque<(u64, EpochTransforms)>,
}

impl Default for EpochTable {
    fn default() -> Self {
        let mut history = VecDeque::with_capacity(RETAINED_EPOCHS);
        history.push_back((0, Arc::new(Vec::new())));
        EpochTable { current: 0, overrides: BTreeMap::new(), history }
    }
}

impl EpochTable {
    pub fn current(&self) -> u64 {
        self.current
    }

    /// Starts `epoch` with `moved` applied on top of the previous epoch's transforms.
    /// Returns false (and changes nothing) unless `epoch` is newer than the current one.
    pub fn advance(&mut self, epoch: u64, moved: &[(u32, Affine3A)]) -> bool {
        if epoch <= self.current {
            return false;
        }
        for &(id, t) in moved {
            self.overrides.insert(id, t);
        }
        let set: Vec<ObjectTransform> = self
            .overrides
            .iter()
            .map(|(&object_id, t)| ObjectTransform { object_id, transform: Some(affine_to_wire(t)) })
            .collect();
        if self.history.len() == RETAINED_EPOCHS {
            self.history.pop_front();
        }
        self.history.push_back((epoch, Arc::new(set)));
        self.current = epoch;
        true
    }

    /// The full transform set of a retained epoch.
    pub fn get(&self, epoch: u64) -> Option<EpochTransforms> {
        self.history.iter().rev().find(|(e, _)| *e == epoch).map(|(_, t)| t.clone())
    }

    /// Is `epoch` one a batch may carry (retained and not in the future)?
    pub fn is_retained(&self, epoch: u64) -> bool {
        self.history.iter().any(|(e, _)| *e == epoch)
    }
}

/// The epochs one link has sent on its current stream, newest last. The worker keeps only a
/// few (~8), so a link treats only its last `WORKER_KEEPS` as still usable.
#[derive(Debug, Default)]
pub struct SentEpochs {
    recent: VecDeque<u64>,
}

/// Epochs a worker is assumed to retain per stream (the worker contract keeps ~8).
pub const WORKER_KEEPS: usize = 8;

/// What a link must do before sending a batch of some epoch.
#[derive(Debug, PartialEq, Eq)]
pub enum EpochAction {
    /// The worker already holds the epoch.
    Ready,
    /// Send the epoch's transforms first (it is newer than anything sent on this stream).
    SendFirst,
    /// The epoch is older than what the stream has moved on to and no longer held: drop.
    Unsendable,
}

impl SentEpochs {
    pub fn action(&self, epoch: u64) -> EpochAction {
        match self.recent.back() {
            None => EpochAction::SendFirst,
            Some(&last) if epoch > last => EpochAction::SendFirst,
            _ if self.recent.contains(&epoch) => EpochAction::Ready,
            _ => EpochAction::Unsendable,
        }
    }

    pub fn record(&mut self, epoch: u64) {
        if self.recent.len() == WORKER_KEEPS {
            self.recent.pop_front();
        }
        self.recent.push_back(epoch);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn epochs_accumulate_full_override_sets() {
        let mut t = EpochTable::default();
        assert_eq!(t.get(0).unwrap().len(), 0);
        let a = Affine3A::from_translation(Vec3::X);
        let b = Affine3A::from_translation(Vec3::Y);
        assert!(t.advance(1, &[(3, a)]));
        assert!(t.advance(2, &[(1, b)]));
        assert!(!t.advance(2, &[(1, a)]), "epochs only increase");
        let e2 = t.get(2).unwrap();
        assert_eq!(e2.iter().map(|o| o.object_id).collect::<Vec<_>>(), vec![1, 3]);
        assert_eq!(t.get(1).unwrap().len(), 1);
        assert!(t.advance(5, &[(3, b)]));
        let e5 = t.get(5).unwrap();
        assert_eq!(e5[1].transform.as_ref().unwrap(), &affine_to_wire(&b));
        assert!(t.get(4).is_none() && t.get(6).is_none());
        for e in 6..6 + RETAINED_EPOCHS as u64 {
            t.advance(e, &[]);
        }
        assert!(!t.is_retained(5), "old epochs are forgotten");
        assert!(t.is_retained(t.current()));
    }

    #[test]
    fn sent_epochs_decide_send_ready_or_drop() {
        let mut s = SentEpochs::default();
        assert_eq!(s.action(4), EpochAction::SendFirst);
        s.record(4);
        assert_eq!(s.action(4), EpochAction::Ready);
        assert_eq!(s.action(3), EpochAction::Unsendable, "older and never sent");
        assert_eq!(s.action(9), EpochAction::SendFirst);
        for e in 5..5 + WORKER_KEEPS as u64 {
            s.record(e);
        }
        assert_eq!(s.action(4), EpochAction::Unsendable, "the worker no longer keeps it");
        assert_eq!(s.action(12), EpochAction::Ready);
    }
}
