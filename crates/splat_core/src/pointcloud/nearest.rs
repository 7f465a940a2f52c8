//! Distances only: the k smallest squared distances from every point to the others, for
//! the filters that need no neighbour indices (SOR scores, mean kNN distance).
//!
//! The same kd-tree walk as `KdTree::map_knn` (own leaf first, then the siblings up to the
//! root, seeded by the previous query's k-th distance, pruned on the same boxes), with two
//! differences that make it cheaper (SOR on the 1M-point bench cloud, tree build included:
//! about 1.6x less CPU time than over `map_knn`):
//! - The k best are a sorted array updated by a branch-free min/max network (see
//!   `Network::offer`); inserting a candidate costs the same few vector instructions
//!   wherever it lands, with no mispredicted loop exit. The values are the k smallest of
//!   the multiset of distances, which does not depend on ties or visiting order.
//! - The walk is compiled twice, once for AVX2 (chosen at run time), so a leaf's
//!   distances, the candidate mask and the network each take a few 4-lane instructions.
//!   Only the instruction width differs: the same f64 subtractions, products and sums in
//!   the same order (no fused multiply-add), so both give the same bits.
//!
//! Above `NETWORK_MAX` neighbours the network is dearer than `map_knn`'s heap, which is used
//! instead.

use rayon::prelude::*;

use super::kdtree::{squared_distance, KdTree, LEAF, LEAVES_PER_RUN};

/// Most neighbours kept by the network (in groups of 4 slots).
pub(super) const NETWORK_MAX: usize = 32;

/// The k smallest squared distances seen, ascending, in the last k of `P` slots (k <= P,
/// P a multiple of 4 so the network is whole vectors). The first P - k slots hold -1, below
/// every squared distance, so they never move; the k-th is then always the last slot, a
/// fixed place the compiler keeps in a register. The other slots start at the search's
/// bound.
struct Network<const P: usize> {
    slots: [f64; P],
    k: usize,
}

impl<const P: usize> Network<P> {
    #[inline(always)]
    fn start(&mut self, bound: f64) {
        self.slots = [bound; P];
        self.slots[..P - self.k].fill(-1.0);
    }

    /// Only distances below this can change the k smallest.
    #[inline(always)]
    fn limit(&self) -> f64 {
        self.slots[P - 1]
    }

    /// The k smallest, ascending.
    #[inline(always)]
    fn smallest(&self) -> &[f64] {
        &self.slots[P - self.k..]
    }

    /// Inserts `d`: slot i becomes max(slot i-1, min(slot i, d)), which keeps the slots
    /// below d, puts d in the first slot above it, shifts the rest up and drops the last.
    /// The -1 slots stay -1 (d >= 0), and a d no smaller than the last slot changes
    /// nothing. Squared distances are never NaN, so the comparisons are a total order.
    #[inline(always)]
    fn offer(&mut self, d: f64) {
        let s = &mut self.slots;
        for i in (1..P).rev() {
            let low = if s[i] < d { s[i] } else { d };
            s[i] = if s[i - 1] > low { s[i - 1] } else { low };
        }
        s[0] = if s[0] < d { s[0] } else { d };
    }
}

/// The search of one query, generic over the network width; everything is inlined into
/// `run_leaves` so that its AVX2 instance vectorises all of it.
struct Search<'t, const P: usize> {
    tree: &'t KdTree,
    q: [f64; 3],
    /// Tree position of the query (not its own neighbour).
    skip: usize,
    best: Network<P>,
    /// `descend`'s explicit stack (recursion would stop the inlining into `run_leaves`):
    /// node, first position, count, box distance. Entries are tested again when popped, as
    /// the bound may have tightened since they were pushed. A tree over at most 2^32
    /// points is 27 levels deep, and each level leaves at most one entry behind.
    stack: [(usize, usize, usize, f64); 64],
}

impl<const P: usize> Search<'_, P> {
    /// Offers the points of one leaf (tree positions `start..start + len`).
    #[inline(always)]
    fn scan_leaf(&mut self, start: usize, len: usize) {
        let t = self.tree;
        let mut d2 = [f64::INFINITY; LEAF];
        let (xs, ys, zs) = (
            &t.xs[start..start + len],
            &t.ys[start..start + len],
            &t.zs[start..start + len],
        );
        for (((d, &x), &y), &z) in d2.iter_mut().zip(xs).zip(ys).zip(zs) {
            *d = squared_distance(&self.q, [x, y, z]);
        }
        if (start..start + len).contains(&self.skip) {
            d2[self.skip - start] = f64::INFINITY;
        }
        // Which points can enter, as bits (branch-free, vectorised), then only those.
        let limit = self.best.limit();
        let mut mask = 0u64;
        for (i, &d) in d2.iter().enumerate() {
            mask |= u64::from(d < limit) << i;
        }
        // The network in a local copy, so that it stays in registers.
        let mut best = Network::<P> {
            slots: self.best.slots,
            k: self.best.k,
        };
        while mask != 0 {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            best.offer(d2[i]);
        }
        self.best.slots = best.slots;
    }

    /// Descends into `node` (tree positions `start..start + len`), nearer child first,
    /// pruning boxes no nearer than the current k-th distance.
    #[inline(always)]
    fn descend(&mut self, node: usize, start: usize, len: usize) {
        self.stack[0] = (node, start, len, 0.0);
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (node, start, len, dist) = self.stack[top];
            if dist >= self.best.limit() {
                continue;
            }
            if len <= LEAF {
                self.scan_leaf(start, len);
                continue;
            }
            let mid = len / 2;
            let left = (2 * node + 1, start, mid);
            let right = (2 * node + 2, start + mid, len - mid);
            let dl = self.tree.box_distance(left.0, &self.q);
            let dr = self.tree.box_distance(right.0, &self.q);
            let (near, far) = if dl <= dr {
                (
                    (left.0, left.1, left.2, dl),
                    (right.0, right.1, right.2, dr),
                )
            } else {
                (
                    (right.0, right.1, right.2, dr),
                    (left.0, left.1, left.2, dl),
                )
            };
            // The far child first, so the near one is searched first.
            // Written unconditionally and kept by moving the top or not: no branch to
            // mispredict (the stack has room for both; see `stack`).
            let limit = self.best.limit();
            self.stack[top] = far;
            top += usize::from(far.3 < limit);
            self.stack[top] = near;
            top += usize::from(near.3 < limit);
        }
    }

    /// The k nearest of the point at `pos` in leaf `leaf`, seeded by `prev_kth` (see
    /// `KdTree::seed_bound`); falls back to an unseeded search if the bound ever leaves a
    /// slot unfilled.
    #[inline(always)]
    fn run(&mut self, leaf: usize, pos: usize, prev_kth: Option<f64>) {
        let t = self.tree;
        self.q = t.point(pos);
        self.skip = pos;
        let bound = prev_kth.map_or(f64::INFINITY, |kth| t.seed_bound(pos, kth));
        self.best.start(bound);
        let (start, len) = t.ranges[leaf];
        self.scan_leaf(start as usize, len as usize);
        let mut node = leaf;
        while node > 0 {
            let sibling = if node % 2 == 1 { node + 1 } else { node - 1 };
            if t.box_distance(sibling, &self.q) < self.best.limit() {
                let (s, l) = t.ranges[sibling];
                self.descend(sibling, s as usize, l as usize);
            }
            node = (node - 1) / 2;
        }
        if bound < f64::INFINITY && self.best.limit() >= bound {
            self.best.start(f64::INFINITY);
            self.descend(0, 0, t.len());
        }
    }
}

/// The searches of one run of leaves, in tree order, each seeded by the one before;
/// `f(pos, squared distances nearest first)` for each point, appended to `out`.
#[inline(always)]
pub(super) fn run_leaves<const P: usize, R>(
    tree: &KdTree,
    k: usize,
    leaves: &[usize],
    f: &impl Fn(usize, &[f64]) -> R,
    out: &mut Vec<R>,
) {
    let mut search = Search {
        tree,
        q: [0.0; 3],
        skip: 0,
        best: Network::<P> {
            slots: [f64::INFINITY; P],
            k,
        },
        stack: [(0, 0, 0, 0.0); 64],
    };
    let mut prev = None;
    for &leaf in leaves {
        let (start, len) = tree.ranges[leaf];
        for pos in start as usize..(start + len) as usize {
            search.run(leaf, pos, prev);
            prev = Some(search.best.limit());
            out.push(f(pos, search.best.smallest()));
        }
    }
}

/// `run_leaves` compiled for AVX2 where the CPU has it.
fn run_leaves_dispatch<const P: usize, R>(
    tree: &KdTree,
    k: usize,
    leaves: &[usize],
    f: &impl Fn(usize, &[f64]) -> R,
    out: &mut Vec<R>,
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        super::nearest_avx2::run_leaves::<P, R>(tree, k, leaves, f, out);
        return;
    }
    run_leaves::<P, R>(tree, k, leaves, f, out);
}

/// Runs `f(pos, squared distances)` for every point (its k nearest others, nearest first),
/// in parallel over the fixed runs of leaves of `KdTree::map_knn`, with the same seeding;
/// returns the results in tree order. The distances are those `map_knn` finds, bit for bit.
pub(super) fn map_knn_distances<R: Send>(
    tree: &KdTree,
    k: usize,
    f: impl Fn(usize, &[f64]) -> R + Sync,
) -> Vec<R> {
    if k > NETWORK_MAX {
        return tree.map_knn(k, |pos, nb| f(pos, nb.squared_distances()));
    }
    let mut leaves = Vec::new();
    tree.leaves(0, &mut leaves);
    let run = |run: &[usize]| {
        let mut out = Vec::new();
        match k.div_ceil(4) {
            1 => run_leaves_dispatch::<4, R>(tree, k, run, &f, &mut out),
            2 => run_leaves_dispatch::<8, R>(tree, k, run, &f, &mut out),
            3 => run_leaves_dispatch::<12, R>(tree, k, run, &f, &mut out),
            4 => run_leaves_dispatch::<16, R>(tree, k, run, &f, &mut out),
            5 => run_leaves_dispatch::<20, R>(tree, k, run, &f, &mut out),
            6 => run_leaves_dispatch::<24, R>(tree, k, run, &f, &mut out),
            7 => run_leaves_dispatch::<28, R>(tree, k, run, &f, &mut out),
            _ => run_leaves_dispatch::<32, R>(tree, k, run, &f, &mut out),
        }
        out
    };
    let chunks: Vec<Vec<R>> = leaves.par_chunks(LEAVES_PER_RUN).map(run).collect();
    chunks.into_iter().flatten().collect()
}

/// The portable instance, for tests comparing it with the AVX2 one.
#[cfg(test)]
pub(super) fn map_knn_distances_portable(tree: &KdTree, k: usize) -> Vec<Vec<f64>> {
    let mut leaves = Vec::new();
    tree.leaves(0, &mut leaves);
    let mut out = Vec::new();
    for run in leaves.chunks(LEAVES_PER_RUN) {
        run_leaves::<32, Vec<f64>>(tree, k, run, &|_, d| d.to_vec(), &mut out);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::Lcg;

    /// Plain reference: every squared distance to the other points (nanoflann's
    /// arithmetic), sorted, the k smallest.
    fn brute(pts: &[[f64; 3]], q: usize, k: usize) -> Vec<f64> {
        let mut all: Vec<f64> = (0..pts.len())
            .filter(|&j| j != q)
            .map(|j| squared_distance(&pts[q], pts[j]))
            .collect();
        all.sort_by(f64::total_cmp);
        all.truncate(k);
        all
    }

    /// Checks `map_knn_distances` (and the portable instance) against brute force, bit
    /// for bit, for every point.
    fn check(pts: &[[f64; 3]], ks: &[usize]) {
        let flat: Vec<f64> = pts.iter().flatten().copied().collect();
        let tree = KdTree::build(&flat);
        for &k in ks {
            let got = map_knn_distances(&tree, k, |pos, d| (tree.id(pos), d.to_vec()));
            assert_eq!(got.len(), pts.len());
            for (q, d) in &got {
                assert_eq!(d, &brute(pts, *q as usize, k), "k {k} query {q}");
            }
            if k <= NETWORK_MAX {
                let portable = map_knn_distances_portable(&tree, k);
                let fast: Vec<Vec<f64>> = got.into_iter().map(|g| g.1).collect();
                assert_eq!(portable, fast, "portable instance, k {k}");
            }
        }
    }

    #[test]
    fn matches_brute_force_on_random_points() {
        let mut rng = Lcg::new(3);
        let pts: Vec<[f64; 3]> = (0..1500)
            .map(|i| {
                let s = if i % 40 == 0 { 4.0 } else { 1.0 };
                [
                    f64::from(rng.uniform()) * s,
                    f64::from(rng.uniform()) * 0.3 * s,
                    f64::from(rng.uniform()) * 0.05 * s,
                ]
            })
            .collect();
        // Every network width (4 to 32 slots, k not a multiple of 4 included) and the
        // heap above NETWORK_MAX.
        check(&pts, &[1, 3, 4, 5, 8, 11, 16, 19, 22, 27, 31, 32, 33, 70]);
    }

    #[test]
    fn matches_brute_force_with_ties_and_duplicates() {
        // A coarse lattice (many equal distances) with repeated points, plus far points.
        let mut rng = Lcg::new(11);
        let mut pts: Vec<[f64; 3]> = (0..1200)
            .map(|_| {
                let mut c = |m: f32| (rng.uniform() * m).floor() as f64 * 0.5;
                [c(12.0), c(12.0), c(3.0)]
            })
            .collect();
        pts.extend((0..40).map(|i| [100.0 + i as f64, -50.0, 7.0]));
        check(&pts, &[1, 5, 19, 32]);
    }

    #[test]
    fn degenerate_clouds() {
        // Collinear and evenly spaced; exactly k + 1 points; identical points with one
        // apart (every seeded bound is then the smallest positive float).
        let line: Vec<[f64; 3]> = (0..700).map(|i| [i as f64 * 0.25, 1.0, -2.0]).collect();
        check(&line, &[2, 19]);
        check(&line[..20], &[19]);
        let mut same = vec![[0.5, 0.5, 0.5]; 300];
        same.push([1.0, 2.0, 3.0]);
        check(&same, &[1, 19]);
    }
}
