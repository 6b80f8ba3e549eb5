//! Which node meshes live on the GPU: one per quadtree node, keyed by the node's identity and
//! the content version of the data it was built from, kept while drawn and dropped after a
//! number of frames unused. Generic over the mesh so the policy is tested without a GPU.

use std::collections::HashMap;

use crate::world::NodeId;

struct Entry<M> {
    mesh: M,
    version: u64,
    last_used: u64,
}

/// Meshes by node, each tagged with the [`NodeData::version`](crate::world::NodeData) it
/// shows.
pub struct ResidentMeshes<M> {
    entries: HashMap<NodeId, Entry<M>>,
    frame: u64,
}

impl<M> Default for ResidentMeshes<M> {
    fn default() -> Self {
        Self { entries: HashMap::new(), frame: 0 }
    }
}

impl<M> ResidentMeshes<M> {
    /// Starts a frame (meshes used from now on count as used in it).
    pub fn begin_frame(&mut self) {
        self.frame += 1;
    }

    /// Marks node `id` at content `version` as drawn this frame, making its mesh with `make`
    /// when none is resident or the resident one shows another version (`make` gets that
    /// outdated mesh, to reuse its storage). Returns whether `make` ran (an upload).
    pub fn use_mesh(&mut self, id: NodeId, version: u64, make: impl FnOnce(Option<M>) -> M) -> bool {
        let frame = self.frame;
        match self.entries.get_mut(&id) {
            Some(e) if e.version == version => {
                e.last_used = frame;
                false
            }
            _ => {
                let old = self.entries.remove(&id).map(|e| e.mesh);
                self.entries.insert(id, Entry { mesh: make(old), version, last_used: frame });
                true
            }
        }
    }

    /// The resident mesh of node `id`, if any.
    pub fn get(&self, id: &NodeId) -> Option<&M> {
        self.entries.get(id).map(|e| &e.mesh)
    }

    /// Drops meshes not drawn during the last `keep_frames` frames and returns them.
    pub fn evict_unused(&mut self, keep_frames: u64) -> Vec<M> {
        let frame = self.frame;
        self.entries.extract_if(|_, e| frame - e.last_used > keep_frames).map(|(_, e)| e.mesh).collect()
    }

    /// Drops the meshes of the nodes `keep` rejects and returns them (room for a frame that
    /// needs every slot).
    pub fn evict_unless(&mut self, keep: impl Fn(&NodeId) -> bool) -> Vec<M> {
        self.entries.extract_if(|id, _| !keep(id)).map(|(_, e)| e.mesh).collect()
    }

    /// Meshes resident now.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no mesh is resident.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// Slots (fixed-size places for one mesh each) in one growable GPU buffer: freed slots are
/// reused before new ones are taken.
#[derive(Debug, Default)]
pub struct Slots {
    free: Vec<u32>,
    next: u32,
    capacity: u32,
}

impl Slots {
    /// Slots in the buffer now.
    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// Slots taken and not given back.
    pub fn in_use(&self) -> u32 {
        self.next - self.free.len() as u32
    }

    /// The capacity needed for `more` slots beyond those in use: the current one if it
    /// suffices, else the next power of two ≥ both `in_use + more` and `min`.
    pub fn capacity_for(&self, more: u32, min: u32) -> u32 {
        let need = self.in_use() + more;
        if need <= self.capacity { self.capacity } else { need.next_power_of_two().max(min) }
    }

    /// Records that the buffer now holds `capacity` slots (never fewer than before).
    pub fn grow(&mut self, capacity: u32) {
        self.capacity = self.capacity.max(capacity);
    }

    /// A free slot: a freed one, else the lowest never used; `None` when all are taken.
    pub fn take(&mut self) -> Option<u32> {
        if let Some(s) = self.free.pop() {
            return Some(s);
        }
        (self.next < self.capacity).then(|| {
            self.next += 1;
            self.next - 1
        })
    }

    /// Gives slot `s` back.
    pub fn give(&mut self, s: u32) {
        debug_assert!(s < self.next && !self.free.contains(&s), "slot {s} given twice or never taken");
        self.free.push(s);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::TileCoord;
    use crate::world::quadtree::{NODE_APRON_GRID, NodeData};

    fn node(h: f32) -> NodeData {
        NodeData::new(NodeId::root(TileCoord::new(0, 0)), vec![h; NODE_APRON_GRID * NODE_APRON_GRID], 1.0)
    }

    /// A node rebuilt with the same identity (e.g. refined data replacing base data, or the
    /// same node freed and made again, possibly at the same address) has a new version and
    /// gets a new mesh; drawing the same data again uploads nothing.
    #[test]
    fn a_rebuilt_node_gets_a_new_mesh_and_the_same_data_none() {
        let mut r = ResidentMeshes::default();
        let a = node(1.0);
        r.begin_frame();
        assert!(r.use_mesh(a.id, a.version, |_| 1.0));
        assert!(!r.use_mesh(a.id, a.version, |_| 2.0), "same version: kept");
        let b = node(1.0);
        assert_ne!(a.version, b.version, "every build has its own version, even with equal heights");
        let mut handed = None;
        assert!(r.use_mesh(b.id, b.version, |old| {
            handed = old;
            3.0
        }));
        assert_eq!(handed, Some(1.0), "the outdated mesh is handed to make");
        assert_eq!(r.get(&b.id), Some(&3.0));
        assert_eq!(r.len(), 1);
        let c = a.clone();
        assert!(r.use_mesh(c.id, c.version, |_| 4.0), "a clone of the old data is the old version");
    }

    /// Meshes not drawn for more than `keep_frames` frames are dropped and returned (once);
    /// drawn ones stay.
    #[test]
    fn unused_meshes_leave_after_keep_frames() {
        let mut r = ResidentMeshes::default();
        let (a, b) = (node(1.0), NodeData { id: NodeId { depth: 1, ..NodeId::root(TileCoord::new(0, 0)) }, ..node(2.0) });
        r.begin_frame();
        r.use_mesh(a.id, a.version, |_| 'a');
        r.use_mesh(b.id, b.version, |_| 'b');
        let mut evicted = Vec::new();
        for _ in 0..3 {
            r.begin_frame();
            r.use_mesh(a.id, a.version, |_| 'x');
            evicted.extend(r.evict_unused(2));
        }
        assert_eq!(evicted, vec!['b']);
        assert_eq!(r.len(), 1);
        assert!(r.get(&a.id).is_some() && r.get(&b.id).is_none());
    }

    /// Slots: taken lowest first up to the capacity, given-back ones reused first; the
    /// capacity for more grows to a power of two and never below the minimum.
    #[test]
    fn slots_are_reused_and_grow_in_powers_of_two() {
        let mut s = Slots::default();
        assert_eq!(s.capacity_for(3, 64), 64);
        s.grow(4);
        assert_eq!((s.take(), s.take(), s.take()), (Some(0), Some(1), Some(2)));
        s.give(1);
        assert_eq!(s.in_use(), 2);
        assert_eq!((s.take(), s.take(), s.take()), (Some(1), Some(3), None));
        assert_eq!(s.capacity_for(0, 1), 4);
        assert_eq!(s.capacity_for(5, 1), 16);
        s.grow(16);
        assert_eq!(s.take(), Some(4));
    }
}
