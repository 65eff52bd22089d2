//! Fixtures several tests of one binary build identically (a simulated flight, its
//! diagnosis, a compensation error), computed once and shared. The tests of a binary run
//! on several threads: the first to ask for a key computes its value while the others
//! asking for the same key wait for it, so nothing is computed twice.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, OnceLock};

/// Values by key, each computed by the first caller.
pub struct Memo<K, V> {
    cells: Mutex<BTreeMap<K, Arc<OnceLock<V>>>>,
}

impl<K: Ord, V: Clone> Memo<K, V> {
    pub const fn new() -> Self {
        Self {
            cells: Mutex::new(BTreeMap::new()),
        }
    }

    /// The value of `key`, made by `make` if no test has asked for it yet.
    pub fn get(&self, key: K, make: impl FnOnce() -> V) -> V {
        let cell = self
            .cells
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .entry(key)
            .or_default()
            .clone();
        cell.get_or_init(make).clone()
    }
}
