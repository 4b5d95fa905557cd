//! The pinned peers: the device IDs the link lets through its handshake
//! (outside pairing mode), shared and updated live.
use std::collections::BTreeSet;
use std::fmt;
use std::sync::{Arc, RwLock};

use crate::device_id::DeviceId;
use crate::trust::TrustStore;

/// A shared, updatable set of pinned device IDs. Clones share the set, so
/// the link's handshake gate sees pairings and unpairings made later.
#[derive(Clone, Default)]
pub struct PinSet(Arc<RwLock<BTreeSet<DeviceId>>>);

impl fmt::Debug for PinSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_set().entries(self.snapshot()).finish()
    }
}

impl PinSet {
    /// A set of these IDs.
    pub fn new(ids: impl IntoIterator<Item = DeviceId>) -> PinSet {
        PinSet(Arc::new(RwLock::new(ids.into_iter().collect())))
    }

    /// The IDs of all peers in a trust store.
    pub fn from_store(store: &TrustStore) -> PinSet {
        PinSet::new(store.device_ids())
    }

    fn read(&self) -> std::sync::RwLockReadGuard<'_, BTreeSet<DeviceId>> {
        self.0.read().unwrap_or_else(|p| p.into_inner())
    }

    fn write(&self) -> std::sync::RwLockWriteGuard<'_, BTreeSet<DeviceId>> {
        self.0.write().unwrap_or_else(|p| p.into_inner())
    }

    /// Whether `id` is pinned.
    pub fn contains(&self, id: &DeviceId) -> bool {
        self.read().contains(id)
    }

    /// Pins `id`; returns whether it was new.
    pub fn insert(&self, id: DeviceId) -> bool {
        self.write().insert(id)
    }

    /// Unpins `id`; returns whether it was there.
    pub fn remove(&self, id: &DeviceId) -> bool {
        self.write().remove(id)
    }

    /// Replaces the set with the peers of `store` (e.g. after re-reading it).
    pub fn replace_from(&self, store: &TrustStore) {
        *self.write() = store.device_ids().collect();
    }

    /// Re-reads the trust store in `dir` and replaces the set with its
    /// peers, so unpairings (and pairings) made by another process, e.g.
    /// `telextilesd unpair`, apply to the next handshake. Blocking file I/O:
    /// call it from a blocking context.
    pub fn reload(&self, dir: &std::path::Path) -> Result<(), crate::StoreError> {
        let store = TrustStore::load(dir)?;
        self.replace_from(&store);
        Ok(())
    }

    /// A copy of the current IDs.
    pub fn snapshot(&self) -> Vec<DeviceId> {
        self.read().iter().copied().collect()
    }
}
