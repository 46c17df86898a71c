//! Scenes shared between sessions. Sessions on the same scene (same content hash) share one
//! parsed [`Scene`] and one edge index (edge trees and receiver hierarchies, paper 000
//! §6.4), built by the first session that needs them and freed when the last session using
//! them ends — so sixteen viewers of the dragon cost one dragon, not sixteen.
use crate::session::EdgeIndexSlot;
use edgepoint_scene::Scene;
use std::collections::HashMap;
use std::sync::{Arc, Mutex, Weak};

/// What a session gets for a scene hash.
pub struct SharedScene {
    pub scene: Arc<Scene>,
    pub edge_index: EdgeIndexSlot,
}

/// A weak [`EdgeIndexSlot`].
type WeakEdgeIndexSlot = Weak<std::sync::OnceLock<Arc<crate::edges::finder::SceneEdgeIndex>>>;

/// Content hash → the scene and edge index sessions hold (weakly: alive while used).
#[derive(Default)]
pub struct SceneLibrary {
    entries: Mutex<HashMap<String, (Weak<Scene>, WeakEdgeIndexSlot)>>,
}

impl SceneLibrary {
    /// The scene of `hash` if a live session holds it, with its edge index slot (a new,
    /// empty one if no session holds the old).
    pub fn get(&self, hash: &str) -> Option<SharedScene> {
        let mut map = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        let (scene, slot) = map.get_mut(hash)?;
        let scene = scene.upgrade()?;
        let edge_index = slot.upgrade().unwrap_or_else(|| {
            let fresh = EdgeIndexSlot::default();
            *slot = Arc::downgrade(&fresh);
            fresh
        });
        Some(SharedScene { scene, edge_index })
    }

    /// Records a freshly built scene; if another session recorded the same hash meanwhile,
    /// that one is returned instead (one copy per hash).
    pub fn insert(&self, hash: &str, scene: Scene) -> SharedScene {
        let mut map = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        map.retain(|_, (s, _)| s.strong_count() > 0);
        if let Some((s, slot)) = map.get_mut(hash) {
            if let Some(s) = s.upgrade() {
                let edge_index = slot.upgrade().unwrap_or_else(|| {
                    let fresh = EdgeIndexSlot::default();
                    *slot = Arc::downgrade(&fresh);
                    fresh
                });
                return SharedScene { scene: s, edge_index };
            }
        }
        let scene = Arc::new(scene);
        let edge_index = EdgeIndexSlot::default();
        map.insert(hash.to_string(), (Arc::downgrade(&scene), Arc::downgrade(&edge_index)));
        SharedScene { scene, edge_index }
    }

    /// Hashes with a live scene.
    pub fn live(&self) -> usize {
        self.entries.lock().unwrap_or_else(|p| p.into_inner()).values().filter(|(s, _)| s.strong_count() > 0).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shared_while_held_and_freed_after() {
        let lib = SceneLibrary::default();
        assert!(lib.get("h").is_none());
        let a = lib.insert("h", edgepoint_scene::builtin::load("cornell").unwrap());
        let b = lib.get("h").expect("held by a");
        assert!(Arc::ptr_eq(&a.scene, &b.scene) && Arc::ptr_eq(&a.edge_index, &b.edge_index));
        let c = lib.insert("h", edgepoint_scene::builtin::load("cornell").unwrap());
        assert!(Arc::ptr_eq(&a.scene, &c.scene), "a racing insert gets the first copy");
        assert_eq!(lib.live(), 1);
        drop((a, b, c));
        assert!(lib.get("h").is_none(), "freed with the last session");
        assert_eq!(lib.live(), 0);
    }
}
