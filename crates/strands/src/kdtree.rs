//! k-nearest-neighbour queries over a fixed point set: a kd-tree built by
//! median splits on the widest axis, stored implicitly in a permuted index
//! array. Exact (not approximate), so the interpolation weights do not
//! depend on the index and match a brute-force search.

use nst3d_core::math::{dist2, V3};

const LEAF: usize = 8;

/// A static kd-tree over a point set, answering exact k-NN queries.
#[derive(Clone, Debug)]
pub struct KdTree {
    points: Vec<V3>,
    /// Point indices, permuted so every node owns a contiguous range.
    order: Vec<u32>,
    nodes: Vec<Node>,
}

#[derive(Clone, Copy, Debug)]
struct Node {
    start: u32,
    end: u32,
    /// Split axis (0..3), or 3 for a leaf.
    axis: u8,
    split: f32,
    /// Children indices (left, right) for inner nodes.
    left: u32,
    right: u32,
}

impl KdTree {
    /// Builds the tree over `points` (copied).
    pub fn new(points: &[[f32; 3]]) -> Self {
        let mut t = KdTree {
            points: points.to_vec(),
            order: (0..points.len() as u32).collect(),
            nodes: Vec::with_capacity(2 * points.len() / LEAF + 1),
        };
        if !points.is_empty() {
            t.build(0, points.len());
        }
        t
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the tree indexes no point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    fn build(&mut self, start: usize, end: usize) -> u32 {
        let id = self.nodes.len() as u32;
        self.nodes.push(Node { start: start as u32, end: end as u32, axis: 3, split: 0.0, left: 0, right: 0 });
        if end - start <= LEAF {
            return id;
        }
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for &i in &self.order[start..end] {
            let p = self.points[i as usize];
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let axis = (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0);
        if hi[axis] <= lo[axis] {
            // All points coincide: splitting cannot separate them.
            return id;
        }
        let mid = (start + end) / 2;
        let pts = &self.points;
        self.order[start..end]
            .select_nth_unstable_by(mid - start, |&a, &b| pts[a as usize][axis].total_cmp(&pts[b as usize][axis]));
        let split = self.points[self.order[mid] as usize][axis];
        let left = self.build(start, mid);
        let right = self.build(mid, end);
        let n = &mut self.nodes[id as usize];
        n.axis = axis as u8;
        n.split = split;
        n.left = left;
        n.right = right;
        id
    }

    /// The `k` nearest indexed points to `q` as `(squared distance, index)`,
    /// closest first (fewer when the tree holds fewer). Ties are broken by
    /// index so results are deterministic.
    pub fn knn(&self, q: [f32; 3], k: usize) -> Vec<(f32, u32)> {
        let mut best: Vec<(f32, u32)> = Vec::with_capacity(k + 1);
        if k == 0 || self.nodes.is_empty() {
            return best;
        }
        let mut stack: Vec<(u32, f32)> = vec![(0, 0.0)];
        while let Some((id, bound)) = stack.pop() {
            if best.len() == k && bound > best[k - 1].0 {
                continue;
            }
            let n = self.nodes[id as usize];
            if n.axis == 3 {
                for &i in &self.order[n.start as usize..n.end as usize] {
                    let d = dist2(q, self.points[i as usize]);
                    if best.len() < k || (d, i) < best[k - 1] {
                        let pos = best.partition_point(|&e| e < (d, i));
                        best.insert(pos, (d, i));
                        best.truncate(k);
                    }
                }
                continue;
            }
            let diff = q[n.axis as usize] - n.split;
            let (near, far) = if diff < 0.0 { (n.left, n.right) } else { (n.right, n.left) };
            // The far side is at least |diff| away along the split axis.
            stack.push((far, bound.max(diff * diff)));
            stack.push((near, bound));
        }
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
        // Duplicate points must not break the build.
        let dup = vec![[1.0, 2.0, 3.0]; 40];
        assert_eq!(KdTree::new(&dup).knn([0.0; 3], 3).len(), 3);
    }
}
