//! In-memory sparse voxel storage: the leaf level of an OpenVDB tree.
//!
//! OpenVDB's upper levels (root, 32³ and 16³ internal nodes) only route
//! lookups to 8³ leaves; once a file is decoded we keep just the leaves,
//! keyed by their origin, with active tiles expanded into full leaves. That is
//! all the rendering and dense conversion need, and it keeps the writer free
//! to rebuild the upper levels from scratch.

use std::collections::BTreeMap;

/// Voxels along one edge of a leaf (OpenVDB `LeafNode` log2 dim 3).
pub const LEAF_DIM: i32 = 8;
/// Voxels in one leaf.
pub const LEAF_VOXELS: usize = 512;

/// Position of voxel `ijk` inside its leaf, in OpenVDB's order
/// (`x` slowest, `z` fastest: `(x & 7) << 6 | (y & 7) << 3 | (z & 7)`), so
/// buffers decode straight from the file without reordering.
#[inline]
pub fn leaf_offset(ijk: [i32; 3]) -> usize {
    (((ijk[0] & 7) << 6) | ((ijk[1] & 7) << 3) | (ijk[2] & 7)) as usize
}

/// Origin (minimum corner) of the leaf holding voxel `ijk`.
#[inline]
pub fn leaf_origin(ijk: [i32; 3]) -> [i32; 3] {
    [ijk[0] & !7, ijk[1] & !7, ijk[2] & !7]
}

/// One 8³ block of voxels: values plus the active-state bit mask.
#[derive(Clone, Debug, PartialEq)]
pub struct Leaf<T> {
    /// Index-space coordinate of voxel 0 (multiple of 8 on each axis).
    pub origin: [i32; 3],
    /// Active bits, bit `n` of the mask is voxel `n` in [`leaf_offset`] order.
    pub active: [u64; 8],
    /// All 512 values in [`leaf_offset`] order; inactive ones usually hold the
    /// background but keep whatever the file stored (as OpenVDB does).
    pub values: Box<[T; LEAF_VOXELS]>,
}

impl<T: Copy> Leaf<T> {
    /// An all-inactive leaf filled with `fill`.
    pub fn new(origin: [i32; 3], fill: T) -> Self {
        Self { origin, active: [0; 8], values: Box::new([fill; LEAF_VOXELS]) }
    }

    /// Whether voxel number `n` ([`leaf_offset`] order) is active.
    #[inline]
    pub fn is_active(&self, n: usize) -> bool {
        self.active[n >> 6] >> (n & 63) & 1 == 1
    }

    /// Number of active voxels.
    pub fn active_count(&self) -> u32 {
        self.active.iter().map(|w| w.count_ones()).sum()
    }

    /// Index-space coordinate of voxel number `n`.
    #[inline]
    pub fn coord(&self, n: usize) -> [i32; 3] {
        let n = n as i32;
        [self.origin[0] + (n >> 6), self.origin[1] + ((n >> 3) & 7), self.origin[2] + (n & 7)]
    }

    /// Active voxels as `(ijk, value)`.
    pub fn iter_active(&self) -> impl Iterator<Item = ([i32; 3], T)> + '_ {
        (0..LEAF_VOXELS).filter(|&n| self.is_active(n)).map(|n| (self.coord(n), self.values[n]))
    }
}

/// A sparse grid of `T`: 8³ leaves keyed by origin plus the background value
/// every voxel outside the leaves takes.
#[derive(Clone, Debug, PartialEq)]
pub struct SparseGrid<T> {
    /// Value of every voxel not stored in a leaf (0 for fog volumes).
    pub background: T,
    leaves: BTreeMap<[i32; 3], Leaf<T>>,
}

impl<T: Copy> SparseGrid<T> {
    /// An empty grid.
    pub fn new(background: T) -> Self {
        Self { background, leaves: BTreeMap::new() }
    }

    /// Leaves in ascending origin order (x, then y, then z).
    pub fn leaves(&self) -> impl Iterator<Item = &Leaf<T>> {
        self.leaves.values()
    }

    /// Leaves in ascending origin order, to change in place.
    pub fn leaves_mut(&mut self) -> impl Iterator<Item = &mut Leaf<T>> {
        self.leaves.values_mut()
    }

    /// Number of leaves.
    pub fn leaf_count(&self) -> usize {
        self.leaves.len()
    }

    /// The leaf with this origin, if any.
    pub fn leaf(&self, origin: [i32; 3]) -> Option<&Leaf<T>> {
        self.leaves.get(&origin)
    }

    /// Inserts (or replaces) a whole leaf; its origin is aligned down to a
    /// multiple of 8 so lookups stay consistent.
    pub fn insert_leaf(&mut self, mut leaf: Leaf<T>) {
        leaf.origin = leaf_origin(leaf.origin);
        self.leaves.insert(leaf.origin, leaf);
    }

    /// The leaf with this origin, created all-inactive (background) if absent.
    pub fn leaf_mut(&mut self, origin: [i32; 3]) -> &mut Leaf<T> {
        let origin = leaf_origin(origin);
        let bg = self.background;
        self.leaves.entry(origin).or_insert_with(|| Leaf::new(origin, bg))
    }

    /// Value at `ijk` (active or not); background outside the leaves.
    pub fn get(&self, ijk: [i32; 3]) -> T {
        match self.leaves.get(&leaf_origin(ijk)) {
            Some(l) => l.values[leaf_offset(ijk)],
            None => self.background,
        }
    }

    /// Whether voxel `ijk` is active.
    pub fn is_active(&self, ijk: [i32; 3]) -> bool {
        self.leaves.get(&leaf_origin(ijk)).is_some_and(|l| l.is_active(leaf_offset(ijk)))
    }

    /// Sets voxel `ijk` to `value` and marks it active.
    pub fn set_active(&mut self, ijk: [i32; 3], value: T) {
        let leaf = self.leaf_mut(ijk);
        let n = leaf_offset(ijk);
        leaf.values[n] = value;
        leaf.active[n >> 6] |= 1 << (n & 63);
    }

    /// Number of active voxels.
    pub fn active_voxel_count(&self) -> u64 {
        self.leaves.values().map(|l| u64::from(l.active_count())).sum()
    }

    /// Active voxels as `(ijk, value)`, leaf by leaf.
    pub fn iter_active(&self) -> impl Iterator<Item = ([i32; 3], T)> + '_ {
        self.leaves.values().flat_map(|l| l.iter_active())
    }

    /// Inclusive `(min, max)` index bounds of the active voxels, `None` when
    /// nothing is active (OpenVDB's `evalActiveVoxelBoundingBox`).
    pub fn active_bbox(&self) -> Option<([i32; 3], [i32; 3])> {
        let mut bb: Option<([i32; 3], [i32; 3])> = None;
        for leaf in self.leaves.values() {
            if leaf.active_count() == 0 {
                continue;
            }
            // A full leaf (expanded tiles, dense smoke) spans its whole 8³ box.
            let (lo, hi) = if leaf.active.iter().all(|&w| w == u64::MAX) {
                let o = leaf.origin;
                (o, [o[0] + 7, o[1] + 7, o[2] + 7])
            } else {
                let mut lo = [i32::MAX; 3];
                let mut hi = [i32::MIN; 3];
                for n in (0..LEAF_VOXELS).filter(|&n| leaf.is_active(n)) {
                    let c = leaf.coord(n);
                    for a in 0..3 {
                        lo[a] = lo[a].min(c[a]);
                        hi[a] = hi[a].max(c[a]);
                    }
                }
                (lo, hi)
            };
            bb = Some(match bb {
                None => (lo, hi),
                Some((a, b)) => (
                    [a[0].min(lo[0]), a[1].min(lo[1]), a[2].min(lo[2])],
                    [b[0].max(hi[0]), b[1].max(hi[1]), b[2].max(hi[2])],
                ),
            });
        }
        bb
    }

    /// The values of the box of `dims` voxels whose first voxel is at index
    /// `origin`, x fastest (the `Grid3` order): voxels outside the leaves
    /// take the background, inactive leaf voxels keep their stored value
    /// (OpenVDB's `copyToDense`). One lookup per leaf the box touches, so a
    /// tile of a huge grid costs the tile's size, not the grid's.
    pub fn region(&self, origin: [i32; 3], dims: [usize; 3]) -> Vec<T> {
        let mut out = vec![self.background; dims.iter().product()];
        for (lorigin, from, to) in leaves_in_box(origin, dims) {
            let Some(leaf) = self.leaves.get(&lorigin) else { continue };
            for z in from[2]..=to[2] {
                for y in from[1]..=to[1] {
                    for x in from[0]..=to[0] {
                        out[box_index(origin, dims, [x, y, z])] = leaf.values[leaf_offset([x, y, z])];
                    }
                }
            }
        }
        out
    }

    /// Writes the box of `dims` voxels at index `origin` (values x fastest)
    /// into the grid leaf by leaf: voxels for which `keep` holds become
    /// active with their value, the others are left as they were. Leaves
    /// that would hold no active voxel are not created.
    pub fn insert_region(&mut self, origin: [i32; 3], dims: [usize; 3], values: &[T], keep: impl Fn(T) -> bool) {
        assert_eq!(values.len(), dims.iter().product::<usize>(), "region values must match its dims");
        for (lorigin, from, to) in leaves_in_box(origin, dims) {
            let kept = |x, y, z| {
                let v = values[box_index(origin, dims, [x, y, z])];
                keep(v).then_some(v)
            };
            let any = (from[2]..=to[2])
                .any(|z| (from[1]..=to[1]).any(|y| (from[0]..=to[0]).any(|x| kept(x, y, z).is_some())));
            if !any {
                continue;
            }
            let leaf = self.leaf_mut(lorigin);
            for z in from[2]..=to[2] {
                for y in from[1]..=to[1] {
                    for x in from[0]..=to[0] {
                        if let Some(v) = kept(x, y, z) {
                            let n = leaf_offset([x, y, z]);
                            leaf.values[n] = v;
                            leaf.active[n >> 6] |= 1 << (n & 63);
                        }
                    }
                }
            }
        }
    }
}

/// The leaves a box of `dims` voxels at `origin` touches: each leaf's
/// origin and the first and last voxel (inclusive) of the box inside it.
fn leaves_in_box(origin: [i32; 3], dims: [usize; 3]) -> impl Iterator<Item = ([i32; 3], [i32; 3], [i32; 3])> {
    let hi: [i32; 3] = std::array::from_fn(|a| origin[a] + dims[a] as i32 - 1);
    let lo = leaf_origin(origin);
    let empty = dims.contains(&0);
    let axis = move |a: usize| (lo[a]..=hi[a]).step_by(LEAF_DIM as usize).take(if empty { 0 } else { usize::MAX });
    axis(2).flat_map(move |lz| {
        axis(1).flat_map(move |ly| {
            axis(0).map(move |lx| {
                let l = [lx, ly, lz];
                let from: [i32; 3] = std::array::from_fn(|a| l[a].max(origin[a]));
                let to: [i32; 3] = std::array::from_fn(|a| (l[a] + LEAF_DIM - 1).min(hi[a]));
                (l, from, to)
            })
        })
    })
}

/// Position of voxel `ijk` in a box of `dims` at `origin`, x fastest.
#[inline]
fn box_index(origin: [i32; 3], dims: [usize; 3], ijk: [i32; 3]) -> usize {
    ((ijk[2] - origin[2]) as usize * dims[1] + (ijk[1] - origin[1]) as usize) * dims[0] + (ijk[0] - origin[0]) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A box that straddles leaves on every side goes in and comes back out
    /// voxel for voxel; what `keep` refuses stays background and inactive,
    /// and leaves with nothing kept are not created.
    #[test]
    fn regions_round_trip_across_leaf_borders() {
        let (origin, dims) = ([-5, 3, 6], [13, 9, 20]);
        let n: usize = dims.iter().product();
        let values: Vec<f32> = (0..n).map(|i| if i % 3 == 0 { 0.0 } else { i as f32 }).collect();
        let mut g = SparseGrid::new(0.0f32);
        g.insert_region(origin, dims, &values, |v| v > 0.0);
        assert_eq!(g.region(origin, dims), values);
        assert_eq!(g.active_voxel_count(), values.iter().filter(|v| **v > 0.0).count() as u64);
        assert!(!g.is_active(origin) && g.is_active([origin[0] + 1, origin[1], origin[2]]));
        // A larger box reads background around the region.
        let big = g.region([-6, 2, 5], [15, 11, 22]);
        assert_eq!(big.iter().filter(|v| **v > 0.0).count() as u64, g.active_voxel_count());
        g.insert_region([40, 40, 40], [3, 3, 3], &[0.0; 27], |v| v > 0.0);
        assert!(g.leaf([40, 40, 40]).is_none());
        assert!(g.region([0, 0, 0], [0, 4, 4]).is_empty());
    }
}
