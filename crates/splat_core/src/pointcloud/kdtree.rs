//! A kd-tree for exact k-nearest-neighbour search over one point set.
//!
//! Median splits on the widest axis with an implicit (heap-numbered) node layout: the shape
//! depends only on the point count, so subtrees build in parallel and the nodes need no
//! pointers. Points are stored in tree order, and inside each leaf ordered by further
//! median splits, so consecutive tree positions are near neighbours: queries issued in that
//! order walk memory that is already cached and each starts from a tight bound taken from
//! the one before. The search visits the cells nanoflann's (the library inside Open3D)
//! would: the query's own leaf first, then, walking up, each sibling subtree only if its
//! cell is closer than the current k-th neighbour. Distances are squared f64 summed
//! x, y, z, exactly as nanoflann's L2 metric does, so the distances found are the same.
//!
//! Identical points are harmless (a known panic of another crate's mutable tree): splits
//! are by rank, not value, so a million copies of one point still give a balanced tree,
//! and cells at distance equal to the current k-th are pruned.

use rayon::prelude::*;

use super::{Coord, OrderKey};

/// Points per leaf (at most 64: a leaf's candidates are one `u64` bit mask). Leaves of 33
/// to 64 points rather than 17 to 32: the search visits fewer cells (fewer
/// unpredictable branches in the walk) for more, cheap, vectorised distances; SOR on the
/// 1M-point bench cloud took 15% less time.
pub(super) const LEAF: usize = 64;
const _: () = assert!(LEAF <= 64);
/// Leaves searched in a row by one worker, each query seeded by the one before (see
/// `map_knn`): fixed, so the runs, and so every result, are independent of threads.
pub(super) const LEAVES_PER_RUN: usize = 16;
/// Subtrees larger than this are built on two threads.
const PARALLEL_BUILD: usize = 1 << 15;

pub struct KdTree {
    /// Coordinates in tree order, one array per axis (a leaf's distances vectorise).
    pub(super) xs: Vec<f64>,
    pub(super) ys: Vec<f64>,
    pub(super) zs: Vec<f64>,
    /// Original index of each tree-order point.
    ids: Vec<u32>,
    /// Bounding box of the points under node `i` (heap numbering: children 2i+1, 2i+2).
    pub(super) boxes: Vec<[[f64; 3]; 2]>,
    /// First tree position and point count under node `i`.
    pub(super) ranges: Vec<(u32, u32)>,
}

/// Above this many neighbours the k best are kept in a binary max-heap (O(log k) per
/// accepted candidate) instead of a sorted array (O(k) per accepted candidate, which made
/// k close to N cost O(N^3): 28 s for 4,000 points). Both keep the same k pairs.
const HEAP_ABOVE: usize = 32;

/// The k best (squared distance, index) pairs seen so far, by (distance, index), each
/// packed into one integer key (see `key`). Unfilled slots hold (bound or +inf, u32::MAX).
/// Small k: a sorted array, worst last (one integer comparison per step of the insertion).
/// Large k: a max-heap, worst first,
/// sorted by `finish` when a search ends. Either way the kept pairs are the k smallest
/// offered, so the result does not depend on the layout.
pub struct Neighbours {
    keys: Vec<u128>,
    heap: bool,
    /// The result once a search has finished, nearest first.
    d2: Vec<f64>,
    id: Vec<u32>,
}

/// Squared distance as nanoflann's L2 metric computes it: f64 differences, squares summed
/// x, y, z in that order (no fused multiply-add), so ties and kept sets match Open3D.
#[inline]
pub(super) fn squared_distance(q: &[f64; 3], p: [f64; 3]) -> f64 {
    let dx = q[0] - p[0];
    let dy = q[1] - p[1];
    let dz = q[2] - p[2];
    dx * dx + dy * dy + dz * dz
}

/// (squared distance, index) as one integer that orders as the pair: squared distances are
/// never negative (nor -0.0: a sum of squares rounds to +0.0), and for such floats the bit
/// pattern orders as the value, +inf included.
#[inline]
fn key(d2: f64, id: u32) -> u128 {
    (u128::from(d2.to_bits()) << 32) | u128::from(id)
}

#[inline]
fn key_distance(key: u128) -> f64 {
    f64::from_bits((key >> 32) as u64)
}

impl Neighbours {
    pub fn new(k: usize) -> Self {
        Self {
            keys: vec![key(f64::INFINITY, u32::MAX); k],
            heap: k > HEAP_ABOVE,
            d2: vec![f64::INFINITY; k],
            id: vec![u32::MAX; k],
        }
    }

    pub fn clear(&mut self) {
        self.clear_within(f64::INFINITY);
    }

    /// Starts a search whose k-th neighbour is known to lie within squared distance
    /// `bound`: slots start at `bound` so farther cells are pruned from the start (equal
    /// slots are a valid heap as well as a sorted array).
    fn clear_within(&mut self, bound: f64) {
        self.keys.fill(key(bound, u32::MAX));
    }

    #[inline]
    fn worst_key(&self) -> u128 {
        if self.heap {
            self.keys[0]
        } else {
            self.keys[self.keys.len() - 1]
        }
    }

    #[inline]
    fn worst(&self) -> f64 {
        key_distance(self.worst_key())
    }

    /// Keeps `key` if it sorts before the current worst.
    #[inline]
    fn offer(&mut self, key: u128) {
        if key >= self.worst_key() {
            return;
        }
        if self.heap {
            self.replace_worst(key);
            return;
        }
        let keys = &mut self.keys[..];
        let mut at = keys.len() - 1;
        while at > 0 {
            let before = keys[at - 1];
            if before <= key {
                break;
            }
            keys[at] = before;
            at -= 1;
        }
        keys[at] = key;
    }

    /// Heap layout: drops the root (the worst) for `key` and sifts it down.
    fn replace_worst(&mut self, key: u128) {
        let n = self.keys.len();
        let mut at = 0;
        loop {
            let left = 2 * at + 1;
            if left >= n {
                break;
            }
            let right = left + 1;
            let big = if right < n && self.keys[right] > self.keys[left] {
                right
            } else {
                left
            };
            if self.keys[big] <= key {
                break;
            }
            self.keys[at] = self.keys[big];
            at = big;
        }
        self.keys[at] = key;
    }

    /// Ends a search: the pairs nearest first into the result slots.
    fn finish(&mut self) {
        if self.heap {
            self.keys.sort_unstable();
        }
        for ((d2, id), &key) in self.d2.iter_mut().zip(self.id.iter_mut()).zip(&self.keys) {
            *d2 = key_distance(key);
            *id = key as u32;
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

/// First tree position and point count of every node of a tree over `n` points with
/// `size` heap-numbered nodes.
fn node_ranges(size: usize, n: usize) -> Vec<(u32, u32)> {
    fn fill(node: usize, start: usize, len: usize, out: &mut [(u32, u32)]) {
        out[node] = (start as u32, len as u32);
        if len > LEAF {
            let mid = len / 2;
            fill(2 * node + 1, start, mid, out);
            fill(2 * node + 2, start + mid, len - mid, out);
        }
    }
    let mut out = vec![(0, 0); size];
    fill(0, 0, n, &mut out);
    out
}

/// Node id, its bounding box (lo, hi).
type NodeInfo = (usize, [f64; 3], [f64; 3]);

/// A point as order keys of its coordinates (see `Coord::Key`) and its original index; the
/// build reorders these in place. Partitioning on integer keys of the input's own width
/// gives the same order as on the f64 values (the keys order as the values, ties broken by
/// index), with one integer comparison per step and, for f32 clouds, half the bytes moved.
type Item<K> = ([K; 3], u32);

/// The tight box (lowest, highest corner) of the points, as keys.
fn bounds<K: OrderKey>(items: &[Item<K>]) -> ([K; 3], [K; 3]) {
    let (first, _) = items[0];
    let (mut lo, mut hi) = (first, first);
    for (p, _) in items {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

/// The axis of widest extent (f64 extents, the first of equal ones).
fn widest<K: OrderKey>(lo: &[K; 3], hi: &[K; 3]) -> usize {
    let extent = |a: usize| hi[a].value() - lo[a].value();
    let mut axis = 0;
    for a in 1..3 {
        if extent(a) > extent(axis) {
            axis = a;
        }
    }
    axis
}

/// Splits `items` at its median along `axis` (by key, then index).
fn split_median<K: OrderKey>(items: &mut [Item<K>], axis: usize) -> usize {
    let mid = items.len() / 2;
    items.select_nth_unstable_by_key(mid, |p| p.0[axis].rank(p.1));
    mid
}

/// Orders a leaf's points by further median splits on the widest axis (no nodes are kept
/// for them): consecutive tree positions are then near neighbours, so each query's search
/// starts from a tight bound taken from the previous one.
fn order_leaf<K: OrderKey>(items: &mut [Item<K>]) {
    if items.len() <= 2 {
        return;
    }
    let (lo, hi) = bounds(items);
    let mid = split_median(items, widest(&lo, &hi));
    let (left, right) = items.split_at_mut(mid);
    order_leaf(left);
    order_leaf(right);
}

fn build_rec<K: OrderKey>(items: &mut [Item<K>], node: usize, out: &mut Vec<NodeInfo>) {
    let len = items.len();
    let (lo, hi) = bounds(items);
    out.push((node, lo.map(K::value), hi.map(K::value)));
    if len <= LEAF {
        order_leaf(items);
        return;
    }
    let mid = split_median(items, widest(&lo, &hi));
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
        let mut items: Vec<Item<T::Key>> = points
            .par_chunks_exact(3)
            .enumerate()
            .map(|(i, p)| {
                (
                    [p[0].order_key(), p[1].order_key(), p[2].order_key()],
                    i as u32,
                )
            })
            .collect();
        let mut nodes = Vec::new();
        build_rec(&mut items, 0, &mut nodes);
        let size = nodes.iter().map(|n| n.0 + 1).max().unwrap_or(0);
        let mut boxes = vec![[[0.0; 3]; 2]; size];
        for (node, lo, hi) in nodes {
            boxes[node] = [lo, hi];
        }
        let axis = |a: usize| items.par_iter().map(|p| p.0[a].value()).collect();
        Self {
            xs: axis(0),
            ys: axis(1),
            zs: axis(2),
            ids: items.par_iter().map(|p| p.1).collect(),
            ranges: node_ranges(size, n),
            boxes,
        }
    }

    pub fn len(&self) -> usize {
        self.ids.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    pub(super) fn point(&self, pos: usize) -> [f64; 3] {
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

    /// A squared distance the k-th neighbour of the point at `pos` lies within, from the
    /// k-th squared distance `prev_kth` of the point at `pos - 1` (triangle inequality:
    /// sqrt(prev_kth) + |pos - prev|, the point `prev` itself included), inflated far past
    /// the rounding of either side.
    pub(super) fn seed_bound(&self, pos: usize, prev_kth: f64) -> f64 {
        let step = squared_distance(&self.point(pos), self.point(pos - 1)).sqrt();
        let r = prev_kth.sqrt() + step;
        (r * r) * (1.0 + 1e-9) + f64::MIN_POSITIVE
    }

    /// Like `knn_of_position` for a point of leaf `leaf`, seeded by the result for the
    /// previous tree position (`prev`, whose k-th squared distance is `prev_kth`; none for
    /// the first point of a run): by the triangle inequality the k-th neighbour of `pos`
    /// lies within sqrt(prev_kth) + |pos - prev| (+ the point `prev` itself), inflated
    /// against rounding. Falls back to an unseeded search if the bound ever leaves a slot
    /// unfilled.
    fn knn_in_leaf(&self, leaf: usize, pos: usize, prev: Option<f64>, out: &mut Neighbours) {
        let q = self.point(pos);
        match prev {
            Some(prev_kth) => out.clear_within(self.seed_bound(pos, prev_kth)),
            None => out.clear(),
        }
        self.search_up(leaf, &q, self.ids[pos], out);
        out.finish();
        if out.id.contains(&u32::MAX) {
            self.knn_of_position(pos, out);
        }
    }

    /// The search of `search` from the root, walked the other way: the query's own leaf
    /// first, then the sibling of each ancestor up to the root, each searched only if its
    /// box is nearer than the k-th neighbour so far. It prunes as the descent from the root
    /// does (and finds the same distances) but skips the descent's 15-odd levels of box
    /// tests on a million points.
    fn search_up(&self, leaf: usize, q: &[f64; 3], skip: u32, out: &mut Neighbours) {
        let (start, len) = self.ranges[leaf];
        self.scan_leaf(start as usize, len as usize, q, skip, out);
        let mut node = leaf;
        while node > 0 {
            let sibling = if node % 2 == 1 { node + 1 } else { node - 1 };
            if self.box_distance(sibling, q) < out.worst() {
                let (s, l) = self.ranges[sibling];
                self.search(sibling, s as usize, l as usize, q, skip, out);
            }
            node = (node - 1) / 2;
        }
    }

    /// Squared distance from `q` to the bounding box of `node`: never more than the
    /// distance to any point in it (the box corners are point coordinates, and rounding is
    /// monotone), so pruning on it is exact.
    #[inline]
    pub(super) fn box_distance(&self, node: usize, q: &[f64; 3]) -> f64 {
        let [lo, hi] = &self.boxes[node];
        // Branch-free: the larger of lo - q and q - hi, or 0 inside (the same values as
        // testing which side q is on; at most one of them is positive).
        let mut d2 = 0.0;
        for a in 0..3 {
            let (below, above) = (lo[a] - q[a], q[a] - hi[a]);
            let d = if below > above { below } else { above };
            let d = if d > 0.0 { d } else { 0.0 };
            d2 += d * d;
        }
        d2
    }

    /// Offers the points at tree positions `start..start + len` (one leaf) to `out`.
    #[inline]
    fn scan_leaf(&self, start: usize, len: usize, q: &[f64; 3], skip: u32, out: &mut Neighbours) {
        // Distances first (a loop the compiler vectorises), then the candidates.
        let mut d2 = [0.0f64; LEAF];
        let (xs, ys, zs) = (
            &self.xs[start..start + len],
            &self.ys[start..start + len],
            &self.zs[start..start + len],
        );
        for (((d, &x), &y), &z) in d2.iter_mut().zip(xs).zip(ys).zip(zs) {
            *d = squared_distance(q, [x, y, z]);
        }
        // Which points can enter, as bits (a vectorised loop without branches), then only
        // those are offered: far fewer unpredictable branches than testing each point.
        let worst = out.worst();
        let mut mask = 0u64;
        for (i, &d) in d2[..len].iter().enumerate() {
            mask |= u64::from(d <= worst) << i;
        }
        let ids = &self.ids[start..start + len];
        while mask != 0 {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let key = key(d2[i], ids[i]);
            if key < out.worst_key() && ids[i] != skip {
                out.offer(key);
            }
        }
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
            self.scan_leaf(start, len, q, skip, out);
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

    /// The leaves under `node`, in tree order (`node` 0: all of them).
    pub(super) fn leaves(&self, node: usize, out: &mut Vec<usize>) {
        if self.ranges[node].1 as usize <= LEAF {
            out.push(node);
        } else {
            self.leaves(2 * node + 1, out);
            self.leaves(2 * node + 2, out);
        }
    }

    /// Runs `f(pos, neighbours)` for every point (k nearest others), in parallel over fixed
    /// runs of leaves; returns the per-position results in tree order.
    pub fn map_knn<R: Send>(&self, k: usize, f: impl Fn(usize, &Neighbours) -> R + Sync) -> Vec<R> {
        // Fixed runs of consecutive leaves, each searched in tree order and seeded by the
        // predecessor.
        let mut leaves = Vec::new();
        self.leaves(0, &mut leaves);
        let chunks: Vec<Vec<R>> = leaves
            .par_chunks(LEAVES_PER_RUN)
            .map_init(
                || Neighbours::new(k),
                |nb, run| {
                    let mut out = Vec::new();
                    let mut prev = None;
                    for &leaf in run {
                        let (start, len) = self.ranges[leaf];
                        for pos in start as usize..(start + len) as usize {
                            self.knn_in_leaf(leaf, pos, prev, nb);
                            prev = Some(nb.d2[nb.d2.len() - 1]);
                            out.push(f(pos, nb));
                        }
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

    /// Checks `map_knn` on `pts` against brute force: the same squared distances, bit for
    /// bit, and indices that are distinct other points at exactly those distances (which
    /// of several tied points is returned may differ).
    fn check_map_knn(pts: &[[f64; 3]], k: usize) {
        let flat: Vec<f64> = pts.iter().flatten().copied().collect();
        let tree = KdTree::build(&flat);
        let got = tree.map_knn(k, |pos, nb| {
            (
                tree.id(pos),
                nb.squared_distances().to_vec(),
                nb.indices().to_vec(),
            )
        });
        for (q, d2, ids) in got {
            let want: Vec<f64> = brute(pts, q as usize, k).iter().map(|p| p.0).collect();
            assert_eq!(d2, want, "k {k} query {q}");
            let mut seen = ids.clone();
            seen.sort_unstable();
            seen.dedup();
            assert_eq!(seen.len(), k, "k {k} query {q}: repeated index");
            for (&id, &d) in ids.iter().zip(&d2) {
                assert_ne!(id, q);
                assert_eq!(brute_pair(pts, q as usize, id as usize), d);
            }
        }
    }

    fn brute_pair(points: &[[f64; 3]], a: usize, b: usize) -> f64 {
        let d = [
            points[a][0] - points[b][0],
            points[a][1] - points[b][1],
            points[a][2] - points[b][2],
        ];
        d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    }

    #[test]
    fn map_knn_matches_brute_force_with_ties_and_duplicates() {
        // A coarse lattice (many equal distances) with repeated points, plus far points.
        let mut s = 99u64;
        let mut rnd = |m: u64| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 33) % m
        };
        let mut pts: Vec<[f64; 3]> = (0..1500)
            .map(|_| {
                [
                    rnd(12) as f64 * 0.5,
                    rnd(12) as f64 * 0.5,
                    rnd(3) as f64 * 0.5,
                ]
            })
            .collect();
        pts.extend((0..40).map(|i| [100.0 + i as f64, -50.0, 7.0]));
        for k in [1, 5, 19, 33, 60] {
            check_map_knn(&pts, k);
        }
    }

    #[test]
    fn map_knn_on_degenerate_clouds() {
        // Collinear, evenly spaced (every point has two equidistant neighbours).
        let line: Vec<[f64; 3]> = (0..700).map(|i| [i as f64 * 0.25, 1.0, -2.0]).collect();
        check_map_knn(&line, 19);
        // Exactly k + 1 points, and a cloud of identical points with one apart.
        check_map_knn(&line[..20], 19);
        let mut same = vec![[0.5, 0.5, 0.5]; 300];
        same.push([1.0, 2.0, 3.0]);
        check_map_knn(&same, 19);
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
