//! k-nearest-neighbour queries over a fixed point set, exact (not
//! approximate), so the interpolation weights do not depend on the index
//! and match a brute-force search.
//!
//! The search is kiddo's immutable k-d tree. It replaced a median-split
//! tree of our own once a benchmark of the field's workload showed it
//! faster (build over 76,500 points and 20,000 queries of 48 neighbours,
//! AMD EPYC Zen 5, one thread: build 8.4 → 4.3 ms, queries 146 → 93 ms;
//! docs/design/performance.md). Our tree broke ties by index; so does this
//! wrapper, so the neighbour lists, and the outputs, are unchanged.

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use nst3d_core::math::{dist2, V3};

/// Points per leaf bucket of the tree.
const BUCKET: usize = 32;

/// A static k-d tree over a point set, answering exact k-NN queries.
#[derive(Clone, Debug)]
pub struct KdTree {
    points: Vec<V3>,
    /// `None` for an empty set (kiddo's tree needs a point).
    tree: Option<ImmutableKdTree<f32, u32, 3, BUCKET>>,
}

impl KdTree {
    /// Builds the tree over `points` (copied).
    pub fn new(points: &[[f32; 3]]) -> Self {
        let tree = (!points.is_empty()).then(|| ImmutableKdTree::new_from_slice(points));
        KdTree { points: points.to_vec(), tree }
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the tree indexes no point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The `k` nearest indexed points to `q` as `(squared distance, index)`,
    /// closest first (fewer when the tree holds fewer). Ties are broken by
    /// index so results are deterministic: one neighbour more is asked for,
    /// and when it ties with the last, every point at that distance is
    /// gathered and the lowest indices kept.
    pub fn knn(&self, q: [f32; 3], k: usize) -> Vec<(f32, u32)> {
        let Some(tree) = &self.tree else { return Vec::new() };
        let n = k.min(self.points.len());
        let Some(want) = std::num::NonZero::new((n + 1).min(self.points.len())) else {
            return Vec::new();
        };
        let ranked = |items: &mut dyn Iterator<Item = u32>| -> Vec<(f32, u32)> {
            let mut v: Vec<(f32, u32)> = items.map(|i| (dist2(q, self.points[i as usize]), i)).collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            v
        };
        let mut best = ranked(&mut tree.nearest_n::<SquaredEuclidean>(&q, want).into_iter().map(|nn| nn.item));
        if n > 0 && best.len() > n && best[n].0 == best[n - 1].0 {
            let r = best[n - 1].0;
            let within = tree.within_unsorted::<SquaredEuclidean>(&q, r.next_up());
            best = ranked(&mut within.into_iter().map(|nn| nn.item));
            best.retain(|e| e.0 <= r);
        }
        best.truncate(n);
        best
    }

    /// The nearest indexed point to `q` as `(squared distance, index)`.
    pub fn nearest(&self, q: [f32; 3]) -> Option<(f32, u32)> {
        self.knn(q, 1).into_iter().next()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nst3d_core::gradcheck::pseudo_random;

    #[test]
    fn knn_matches_brute_force() {
        let r = pseudo_random(3 * 500, 3);
        let pts: Vec<V3> = r.chunks(3).map(|c| [c[0], c[1] * 0.2, c[2]]).collect();
        let tree = KdTree::new(&pts);
        let qs = pseudo_random(3 * 50, 4);
        for q in qs.chunks(3) {
            let q = [q[0] * 1.5, q[1], q[2] * 1.5];
            let got = tree.knn(q, 7);
            let mut all: Vec<(f32, u32)> = pts.iter().enumerate().map(|(i, p)| (dist2(q, *p), i as u32)).collect();
            all.sort_by(|a, b| a.partial_cmp(b).unwrap());
            assert_eq!(got, all[..7].to_vec());
        }
        // Duplicate points must not break the build; ties go to the lowest indices.
        let dup = vec![[1.0, 2.0, 3.0]; 40];
        assert_eq!(KdTree::new(&dup).knn([0.0; 3], 3), vec![(14.0, 0), (14.0, 1), (14.0, 2)]);
        assert!(KdTree::new(&[]).knn([0.0; 3], 3).is_empty());
    }

    /// On a lattice most neighbour lists end in a tie; the tree keeps the
    /// lowest indices among the tied, as a brute-force search sorted by
    /// (distance, index) does.
    #[test]
    fn ties_at_the_last_neighbour_go_to_the_lowest_indices() {
        let pts: Vec<V3> = (0..216).map(|i| [(i % 6) as f32, (i / 6 % 6) as f32, (i / 36) as f32]).collect();
        let tree = KdTree::new(&pts);
        for (q, k) in [([2.0, 2.0, 2.0], 5), ([2.5, 2.0, 2.0], 9), ([0.0, 0.0, 0.0], 48), ([2.5, 2.5, 2.5], 7)] {
            let mut all: Vec<(f32, u32)> = pts.iter().enumerate().map(|(i, p)| (dist2(q, *p), i as u32)).collect();
            all.sort_by(|a, b| a.partial_cmp(b).unwrap());
            assert_eq!(tree.knn(q, k), all[..k].to_vec(), "{q:?} k {k}");
        }
    }
}
