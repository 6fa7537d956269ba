//! The node index: a uniform grid over node boxes, so association never scans the map.

use glam::{IVec3, Vec3};
use rustc_hash::FxHashMap;

use super::cloud::{cell_of, key};

/// Uniform grid over node boxes: cell → node slots whose (grown) box touches it.
#[derive(Debug, Default)]
pub(super) struct NodeIndex {
    pub(super) cell_m: f32,
    pub(super) cells: FxHashMap<u64, Vec<u32>>,
    /// Per slot, the query stamp that last returned it (dedupe without a set).
    pub(super) marks: Vec<u32>,
    pub(super) stamp: u32,
}

impl NodeIndex {
    pub(super) fn range(&self, min: Vec3, max: Vec3) -> (IVec3, IVec3) {
        (cell_of(min, self.cell_m), cell_of(max, self.cell_m))
    }

    pub(super) fn for_cells(range: (IVec3, IVec3), mut f: impl FnMut(IVec3)) {
        for x in range.0.x..=range.1.x {
            for y in range.0.y..=range.1.y {
                for z in range.0.z..=range.1.z {
                    f(IVec3::new(x, y, z));
                }
            }
        }
    }

    pub(super) fn insert(&mut self, slot: u32, range: (IVec3, IVec3)) {
        Self::for_cells(range, |c| self.cells.entry(key(c)).or_default().push(slot));
    }

    pub(super) fn remove(&mut self, slot: u32, range: (IVec3, IVec3)) {
        Self::for_cells(range, |c| {
            if let Some(list) = self.cells.get_mut(&key(c))
                && let Some(at) = list.iter().position(|s| *s == slot)
            {
                list.swap_remove(at);
            }
        });
    }

    /// Slots whose cells touch the box `[min, max]`, each once, into `out`.
    pub(super) fn query(&mut self, min: Vec3, max: Vec3, out: &mut Vec<u32>) {
        out.clear();
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.marks.fill(0);
            self.stamp = 1;
        }
        let range = self.range(min, max);
        let (cells, marks, stamp) = (&self.cells, &mut self.marks, self.stamp);
        Self::for_cells(range, |c| {
            if let Some(list) = cells.get(&key(c)) {
                for &slot in list {
                    let mark = &mut marks[slot as usize];
                    if *mark != stamp {
                        *mark = stamp;
                        out.push(slot);
                    }
                }
            }
        });
    }

    pub(super) fn heap_bytes(&self) -> usize {
        self.cells.capacity() * (size_of::<(u64, Vec<u32>)>() + 1)
            + self.cells.values().map(|v| v.capacity() * size_of::<u32>()).sum::<usize>()
            + self.marks.capacity() * size_of::<u32>()
    }
}
