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
    /// when none is resident or the resident one shows another version. Returns whether
    /// `make` ran (an upload).
    pub fn use_mesh(&mut self, id: NodeId, version: u64, make: impl FnOnce() -> M) -> bool {
        let frame = self.frame;
        match self.entries.get_mut(&id) {
            Some(e) if e.version == version => {
                e.last_used = frame;
                false
            }
            _ => {
                self.entries.insert(id, Entry { mesh: make(), version, last_used: frame });
                true
            }
        }
    }

    /// The resident mesh of node `id`, if any.
    pub fn get(&self, id: &NodeId) -> Option<&M> {
        self.entries.get(id).map(|e| &e.mesh)
    }

    /// Drops meshes not drawn during the last `keep_frames` frames.
    pub fn evict_unused(&mut self, keep_frames: u64) {
        let frame = self.frame;
        self.entries.retain(|_, e| frame - e.last_used <= keep_frames);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::quadtree::{NODE_APRON_GRID, NodeData};
    use crate::world::TileCoord;

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
        assert!(r.use_mesh(a.id, a.version, || 1.0));
        assert!(!r.use_mesh(a.id, a.version, || 2.0), "same version: kept");
        let b = node(1.0);
        assert_ne!(a.version, b.version, "every build has its own version, even with equal heights");
        assert!(r.use_mesh(b.id, b.version, || 3.0));
        assert_eq!(r.get(&b.id), Some(&3.0));
        assert_eq!(r.len(), 1);
        let c = a.clone();
        assert!(r.use_mesh(c.id, c.version, || 4.0), "a clone of the old data is the old version");
    }

    /// Meshes not drawn for more than `keep_frames` frames are dropped; drawn ones stay.
    #[test]
    fn unused_meshes_leave_after_keep_frames() {
        let mut r = ResidentMeshes::default();
        let (a, b) = (node(1.0), NodeData { id: NodeId { depth: 1, ..NodeId::root(TileCoord::new(0, 0)) }, ..node(2.0) });
        r.begin_frame();
        r.use_mesh(a.id, a.version, || ());
        r.use_mesh(b.id, b.version, || ());
        for _ in 0..3 {
            r.begin_frame();
            r.use_mesh(a.id, a.version, || ());
            r.evict_unused(2);
        }
        assert_eq!(r.len(), 1);
        assert!(r.get(&a.id).is_some() && r.get(&b.id).is_none());
    }
}
