//! A kd-tree for exact k-nearest-neighbour search over one point set.
//!
//! Median splits on the widest axis with an implicit (heap-numbered) node layout: the shape
//! depends only on the point count, so subtrees build in parallel and the nodes need no
//! pointers. Points are stored in tree order, so queries issued in that order walk memory
//! that is already cached. The search is nanoflann's (the library inside Open3D): nearer
//! child first, then the farther one only if its cell is closer than the current k-th
//! neighbour, tracking the cell distance per axis. Distances are squared f64 summed
//! x, y, z, exactly as nanoflann's L2 metric does.
//!
//! Identical points are harmless (a known panic of another crate's mutable tree): splits
//! are by rank, not value, so a million copies of one point still give a balanced tree,
//! and cells at distance equal to the current k-th are pruned.

use rayon::prelude::*;

use super::{point, Coord};

/// Points per leaf.
const LEAF: usize = 32;
/// Subtrees larger than this are built on two threads.
const PARALLEL_BUILD: usize = 1 << 15;

pub struct KdTree {
    /// Coordinates in tree order, one array per axis (a leaf's distances vectorise).
    xs: Vec<f64>,
    ys: Vec<f64>,
    zs: Vec<f64>,
    /// Original index of each tree-order point.
    ids: Vec<u32>,
    /// Bounding box of the points under node `i` (heap numbering: children 2i+1, 2i+2).
    boxes: Vec<[[f64; 3]; 2]>,
}

/// Above this many neighbours the k best are kept in a binary max-heap (O(log k) per
/// accepted candidate) instead of a sorted array (O(k) per accepted candidate, which made
/// k close to N cost O(N^3): 28 s for 4,000 points). Both keep the same k pairs.
const HEAP_ABOVE: usize = 32;

/// The k best (squared distance, index) pairs seen so far, by (distance, index). Unfilled
/// slots hold (bound or +inf, u32::MAX). Small k: a sorted array, worst last. Large k: a
/// max-heap, worst first, sorted by `finish` when a search ends. Either way the kept pairs
/// are the k smallest offered, so the result does not depend on the layout.
pub struct Neighbours {
    d2: Vec<f64>,
    id: Vec<u32>,
    heap: bool,
}

impl Neighbours {
    pub fn new(k: usize) -> Self {
        Self {
            d2: vec![f64::INFINITY; k],
            id: vec![u32::MAX; k],
            heap: k > HEAP_ABOVE,
        }
    }

    pub fn clear(&mut self) {
        self.clear_within(f64::INFINITY);
    }

    /// Starts a search whose k-th neighbour is known to lie within squared distance
    /// `bound`: slots start at `bound` so farther cells are pruned from the start (equal
    /// slots are a valid heap as well as a sorted array).
    fn clear_within(&mut self, bound: f64) {
        self.d2.fill(bound);
        self.id.fill(u32::MAX);
    }

    #[inline]
    fn worst_at(&self) -> usize {
        if self.heap {
            0
        } else {
            self.d2.len() - 1
        }
    }

    #[inline]
    fn worst(&self) -> f64 {
        self.d2[self.worst_at()]
    }

    /// (d2, id) sorts after slot `at`.
    #[inline]
    fn after(&self, d2: f64, id: u32, at: usize) -> bool {
        d2 > self.d2[at] || (d2 == self.d2[at] && id > self.id[at])
    }

    #[inline]
    fn offer(&mut self, d2: f64, id: u32) {
        let w = self.worst_at();
        if d2 > self.d2[w] || (d2 == self.d2[w] && id >= self.id[w]) {
            return;
        }
        if self.heap {
            self.replace_worst(d2, id);
            return;
        }
        let mut at = w;
        while at > 0 && (self.d2[at - 1] > d2 || (self.d2[at - 1] == d2 && self.id[at - 1] > id)) {
            self.d2[at] = self.d2[at - 1];
            self.id[at] = self.id[at - 1];
            at -= 1;
        }
        self.d2[at] = d2;
        self.id[at] = id;
    }

    /// Heap layout: drops the root (the worst) for (d2, id) and sifts it down.
    fn replace_worst(&mut self, d2: f64, id: u32) {
        let n = self.d2.len();
        let mut at = 0;
        loop {
            let left = 2 * at + 1;
            if left >= n {
                break;
            }
            let right = left + 1;
            let big = if right < n && self.after(self.d2[right], self.id[right], left) {
                right
            } else {
                left
            };
            if !self.after_pair(big, d2, id) {
                break;
            }
            self.d2[at] = self.d2[big];
            self.id[at] = self.id[big];
            at = big;
        }
        self.d2[at] = d2;
        self.id[at] = id;
    }

    /// Slot `at` sorts after (d2, id).
    #[inline]
    fn after_pair(&self, at: usize, d2: f64, id: u32) -> bool {
        self.d2[at] > d2 || (self.d2[at] == d2 && self.id[at] > id)
    }

    /// Ends a search: sorts a heap nearest first (a sorted array already is).
    fn finish(&mut self) {
        if !self.heap {
            return;
        }
        let mut pairs: Vec<(f64, u32)> = self
            .d2
            .iter()
            .copied()
            .zip(self.id.iter().copied())
            .collect();
        pairs.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for (slot, (d2, id)) in pairs.into_iter().enumerate() {
            self.d2[slot] = d2;
            self.id[slot] = id;
        }
    }

    /// Squared distances, nearest first (all k slots are filled once a search has run
    /// over a cloud of more than k points).
    pub fn squared_distances(&self) -> &[f64] {
        &self.d2
    }

    pub fn indices(&self) -> &[u32] {
        &self.id
    }
}

/// Node id, its bounding box (lo, hi).
type NodeInfo = (usize, [f64; 3], [f64; 3]);

/// A point and its original index; the build reorders these in place.
type Item = ([f64; 3], u32);

fn build_rec(items: &mut [Item], node: usize, out: &mut Vec<NodeInfo>) {
    let len = items.len();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for (p, _) in items.iter() {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    out.push((node, lo, hi));
    if len <= LEAF {
        return;
    }
    let mut axis = 0;
    for a in 1..3 {
        if hi[a] - lo[a] > hi[axis] - lo[axis] {
            axis = a;
        }
    }
    let mid = len / 2;
    items.select_nth_unstable_by(mid, |a, b| {
        a.0[axis].total_cmp(&b.0[axis]).then(a.1.cmp(&b.1))
    });
    let (left, right) = items.split_at_mut(mid);
    if len > PARALLEL_BUILD {
        let mut right_out = Vec::new();
        rayon::join(
            || build_rec(left, 2 * node + 1, out),
            || build_rec(right, 2 * node + 2, &mut right_out),
        );
        out.extend(right_out);
    } else {
        build_rec(left, 2 * node + 1, out);
        build_rec(right, 2 * node + 2, out);
    }
}

impl KdTree {
    /// Builds the tree over a validated flat xyz slice (see `check_points`).
    pub fn build<T: Coord>(points: &[T]) -> Self {
        let n = points.len() / 3;
        let mut items: Vec<Item> = (0..n)
            .into_par_iter()
            .map(|i| (point(points, i), i as u32))
            .collect();
        let mut nodes = Vec::new();
        build_rec(&mut items, 0, &mut nodes);
        let size = nodes.iter().map(|n| n.0 + 1).max().unwrap_or(0);
        let mut boxes = vec![[[0.0; 3]; 2]; size];
        for (node, lo, hi) in nodes {
            boxes[node] = [lo, hi];
        }
        let (pts, ids): (Vec<[f64; 3]>, Vec<u32>) = items.into_par_iter().unzip();
        let axis = |a: usize| pts.par_iter().map(|p| p[a]).collect();
        Self {
            xs: axis(0),
            ys: axis(1),
            zs: axis(2),
            ids,
            boxes,
        }
    }

    pub fn len(&self) -> usize {
        self.ids.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    fn point(&self, pos: usize) -> [f64; 3] {
        [self.xs[pos], self.ys[pos], self.zs[pos]]
    }

    /// Original index of the point stored at tree position `pos`.
    pub fn id(&self, pos: usize) -> u32 {
        self.ids[pos]
    }

    /// Position in tree order of each original index.
    pub fn positions(&self) -> Vec<u32> {
        let mut inv = vec![0u32; self.len()];
        for (pos, &id) in self.ids.iter().enumerate() {
            inv[id as usize] = pos as u32;
        }
        inv
    }

    /// The k nearest points to the point at tree position `pos`, excluding that point.
    pub fn knn_of_position(&self, pos: usize, out: &mut Neighbours) {
        out.clear();
        let q = self.point(pos);
        let skip = self.ids[pos];
        self.search(0, 0, self.len(), &q, skip, out);
        out.finish();
    }

    /// Like `knn_of_position`, seeded by the result for the previous tree position
    /// (`prev`, whose k-th squared distance is `prev_kth`): by the triangle inequality
    /// the k-th neighbour of `pos` lies within sqrt(prev_kth) + |pos - prev| (+ the point
    /// `prev` itself), inflated against rounding. Falls back to an unseeded search if the
    /// bound ever leaves a slot unfilled.
    fn knn_of_position_after(&self, pos: usize, prev: usize, prev_kth: f64, out: &mut Neighbours) {
        let q = self.point(pos);
        let p = self.point(prev);
        let step = ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt();
        let r = prev_kth.sqrt() + step;
        let bound = (r * r) * (1.0 + 1e-9) + f64::MIN_POSITIVE;
        out.clear_within(bound);
        self.search(0, 0, self.len(), &q, self.ids[pos], out);
        out.finish();
        if out.id.contains(&u32::MAX) {
            self.knn_of_position(pos, out);
        }
    }

    /// Squared distance from `q` to the bounding box of `node`: never more than the
    /// distance to any point in it (the box corners are point coordinates, and rounding is
    /// monotone), so pruning on it is exact.
    #[inline]
    fn box_distance(&self, node: usize, q: &[f64; 3]) -> f64 {
        let [lo, hi] = &self.boxes[node];
        let mut d2 = 0.0;
        for a in 0..3 {
            let d = if q[a] < lo[a] {
                lo[a] - q[a]
            } else if q[a] > hi[a] {
                q[a] - hi[a]
            } else {
                0.0
            };
            d2 += d * d;
        }
        d2
    }

    fn search(
        &self,
        node: usize,
        start: usize,
        len: usize,
        q: &[f64; 3],
        skip: u32,
        out: &mut Neighbours,
    ) {
        if len <= LEAF {
            // Distances first (a loop the compiler vectorises), then the candidates.
            let mut d2 = [0.0f64; LEAF];
            let (xs, ys, zs) = (
                &self.xs[start..start + len],
                &self.ys[start..start + len],
                &self.zs[start..start + len],
            );
            for (((d, x), y), z) in d2.iter_mut().zip(xs).zip(ys).zip(zs) {
                let dx = q[0] - x;
                let dy = q[1] - y;
                let dz = q[2] - z;
                *d = dx * dx + dy * dy + dz * dz;
            }
            for (&d, &id) in d2[..len].iter().zip(&self.ids[start..start + len]) {
                if d <= out.worst() && id != skip {
                    out.offer(d, id);
                }
            }
            return;
        }
        let mid = len / 2;
        let left = (2 * node + 1, start, mid);
        let right = (2 * node + 2, start + mid, len - mid);
        let dl = self.box_distance(left.0, q);
        let dr = self.box_distance(right.0, q);
        let ((a, da), (b, db)) = if dl <= dr {
            ((left, dl), (right, dr))
        } else {
            ((right, dr), (left, dl))
        };
        if da < out.worst() {
            self.search(a.0, a.1, a.2, q, skip, out);
        }
        if db < out.worst() {
            self.search(b.0, b.1, b.2, q, skip, out);
        }
    }

    /// Runs `f(pos, neighbours)` for every point (k nearest others), in parallel over fixed
    /// chunks of tree order; returns the per-position results in tree order.
    pub fn map_knn<R: Send>(&self, k: usize, f: impl Fn(usize, &Neighbours) -> R + Sync) -> Vec<R> {
        // Fixed chunks of consecutive tree positions, each searched in order and seeded by
        // its predecessor: the chunking, and so every result, is independent of threads.
        const CHUNK: usize = 512;
        let chunks: Vec<Vec<R>> = (0..self.len().div_ceil(CHUNK))
            .into_par_iter()
            .map_init(
                || Neighbours::new(k),
                |nb, c| {
                    let range = c * CHUNK..((c + 1) * CHUNK).min(self.len());
                    let mut out = Vec::with_capacity(range.len());
                    for pos in range.clone() {
                        if pos == range.start {
                            self.knn_of_position(pos, nb);
                        } else {
                            let kth = nb.d2[nb.d2.len() - 1];
                            self.knn_of_position_after(pos, pos - 1, kth, nb);
                        }
                        out.push(f(pos, nb));
                    }
                    out
                },
            )
            .collect();
        chunks.into_iter().flatten().collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(points: &[[f64; 3]], q: usize, k: usize) -> Vec<(f64, u32)> {
        let mut all: Vec<(f64, u32)> = points
            .iter()
            .enumerate()
            .filter(|(i, _)| *i != q)
            .map(|(i, p)| {
                let d = [
                    points[q][0] - p[0],
                    points[q][1] - p[1],
                    points[q][2] - p[2],
                ];
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2], i as u32)
            })
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        all.truncate(k);
        all
    }

    #[test]
    fn matches_brute_force_on_random_points() {
        let mut s = 12345u64;
        let mut rnd = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let pts: Vec<[f64; 3]> = (0..2000)
            .map(|_| [rnd(), rnd() * 0.3, rnd() * 2.0])
            .collect();
        let flat: Vec<f64> = pts.iter().flatten().copied().collect();
        let tree = KdTree::build(&flat);
        let inv = tree.positions();
        // A sorted array (small k) and a heap (large k, up to every other point).
        for k in [7, HEAP_ABOVE + 1, 200, 1999] {
            let mut nb = Neighbours::new(k);
            for q in (0..2000).step_by(97) {
                tree.knn_of_position(inv[q] as usize, &mut nb);
                let want = brute(&pts, q, k);
                let got: Vec<(f64, u32)> = nb
                    .squared_distances()
                    .iter()
                    .copied()
                    .zip(nb.indices().iter().copied())
                    .collect();
                assert_eq!(got, want, "k {k} query {q}");
            }
            // The seeded search of map_knn keeps the same neighbours.
            let seeded = tree.map_knn(k, |pos, nb| (pos, nb.indices().to_vec()));
            for (pos, ids) in seeded.into_iter().step_by(89) {
                tree.knn_of_position(pos, &mut nb);
                assert_eq!(ids, nb.indices(), "k {k} position {pos}");
            }
        }
    }

    #[test]
    fn many_identical_points_neither_panic_nor_hang() {
        let mut flat = vec![0.5f32; 3 * 50_000];
        flat.extend_from_slice(&[1.0, 2.0, 3.0]);
        let tree = KdTree::build(&flat);
        let d = tree.map_knn(20, |_, nb| nb.squared_distances()[19]);
        let far = tree.positions()[50_000] as usize;
        assert!(d
            .iter()
            .enumerate()
            .all(|(pos, &x)| if pos == far { x > 0.0 } else { x == 0.0 }));
    }
}
