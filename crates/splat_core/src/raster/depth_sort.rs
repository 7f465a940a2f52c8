//! Visible splats in depth order: a parallel, stable LSD radix sort of (depth, index) words.
//!
//! The work is cut into chunks of the input. Each pass counts its digit per chunk in
//! parallel, turns the counts into output offsets (digit-major, chunk order within a digit)
//! and scatters every chunk in parallel to its own offsets. Chunk c's elements of a digit
//! land after those of chunks before it and in their input order, so each pass is the
//! stable counting sort a single thread would do. The words are distinct (the index is in
//! them), so their sorted order is unique: the chunking, which follows the thread count,
//! cannot change the result, and one thread runs the sequential sort with no chunks.
#![allow(unsafe_code)]

use rayon::prelude::*;

use super::project::Splat;

/// Bits per digit: a 16 KiB histogram, in L1. Depths of one scene span a few binades and
/// are sorted as offsets from the smallest one, so two passes usually cover them.
const BITS: u32 = 12;
const MASK: u64 = (1 << BITS) - 1;
const BUCKETS: usize = 1 << BITS;
/// Elements per chunk at least (smaller inputs are one chunk: the offsets cost
/// `BUCKETS` per chunk and pass), chunks per thread (for balance), and chunks at most.
const MIN_CHUNK: usize = 16_384;
const CHUNKS_PER_THREAD: usize = 4;
const MAX_CHUNKS: usize = 64;

/// Visible splats ordered front to back; ties broken by index, so the order is unique.
pub fn depth_order(splats: &[Splat]) -> Vec<u32> {
    // Depths of visible splats are >= near_plane > 0, so their bit patterns sort like the
    // values. Collected in index order (rayon keeps it), a stable sort by depth breaks ties
    // by index.
    let visible = |(g, s): (usize, &Splat)| {
        let depth = s.depth.to_bits();
        s.visible().then_some(pair(depth, g as u32))
    };
    if rayon::current_num_threads() == 1 {
        return radix_sort_pairs(splats.iter().enumerate().filter_map(visible).collect());
    }
    let pairs = splats.par_iter().enumerate().filter_map(visible).collect();
    radix_sort_pairs(pairs)
}

/// A key and an id in one word: key in the high half.
#[inline(always)]
pub(super) fn pair(key: u32, id: u32) -> u64 {
    (u64::from(key) << 32) | u64::from(id)
}

#[inline(always)]
fn key(p: u64) -> u32 {
    (p >> 32) as u32
}

/// Elements per chunk for `n` elements on the current pool.
fn chunk_len(n: usize) -> usize {
    let chunks = (CHUNKS_PER_THREAD * rayon::current_num_threads()).min(MAX_CHUNKS);
    n.div_ceil(chunks).max(MIN_CHUNK)
}

/// Stable LSD radix sort of (key, id) `pair`s by key; returns the ids. Linear, and ~4x
/// faster than a comparison sort at 100k splats. Only the bits in which the keys differ
/// from the smallest one cost passes, and a pass whose digit is the same for every key is
/// skipped. Key and id travel as one word, so a pass scatters into one array, not two.
pub(super) fn radix_sort_pairs(mut pairs: Vec<u64>) -> Vec<u32> {
    let n = pairs.len();
    if n == 0 {
        return Vec::new();
    }
    let chunk = chunk_len(n);
    if chunk >= n || rayon::current_num_threads() == 1 {
        // The same order (a stable sort's is unique), with one read for every histogram.
        return sort_on_one_thread(pairs);
    }
    let (min, max) = pairs
        .par_chunks(chunk)
        .map(|c| {
            c.iter().fold((u32::MAX, 0), |(lo, hi), &p| {
                (lo.min(key(p)), hi.max(key(p)))
            })
        })
        .reduce(|| (u32::MAX, 0), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    let span = max - min;
    let passes = (u32::BITS - span.leading_zeros()).div_ceil(BITS);
    let offset = pair(min, 0);
    let mut out = vec![0u64; n];
    for d in 0..passes {
        let shift = 32 + d * BITS;
        let digit = move |p: u64| ((p >> shift) & MASK) as usize;
        let mut offsets: Vec<[u32; BUCKETS]> = if d == 0 {
            // The first count also takes the smallest key off (one read less).
            pairs
                .par_chunks_mut(chunk)
                .map(|c| {
                    let mut h = [0u32; BUCKETS];
                    for p in c {
                        *p -= offset;
                        h[digit(*p)] += 1;
                    }
                    h
                })
                .collect()
        } else {
            pairs
                .par_chunks(chunk)
                .map(|c| {
                    let mut h = [0u32; BUCKETS];
                    for &p in c {
                        h[digit(p)] += 1;
                    }
                    h
                })
                .collect()
        };
        let first = digit(pairs[0]);
        if offsets.iter().map(|h| h[first] as usize).sum::<usize>() == n {
            continue;
        }
        let mut at = 0u32;
        for b in 0..BUCKETS {
            for h in offsets.iter_mut() {
                (h[b], at) = (at, at + h[b]);
            }
        }
        let dst = SharedOut(out.as_mut_ptr());
        pairs
            .par_chunks(chunk)
            .zip(offsets.par_iter_mut())
            .for_each(|(c, slots)| {
                for &p in c {
                    let slot = &mut slots[digit(p)];
                    // SAFETY: the offsets give every (chunk, digit) its own range of
                    // `out`, of exactly the chunk's count of that digit, and the ranges
                    // tile 0..n; each chunk writes only its own ranges, once per slot, so
                    // no two writes alias and all stay in bounds (n = out.len()).
                    unsafe { dst.write(*slot as usize, p) };
                    *slot += 1;
                }
            });
        std::mem::swap(&mut pairs, &mut out);
    }
    pairs.par_iter().map(|&p| p as u32).collect()
}

/// `radix_sort_pairs` on the calling thread: the key range in one read, every pass's
/// histogram in one more, then the passes.
fn sort_on_one_thread(mut pairs: Vec<u64>) -> Vec<u32> {
    let n = pairs.len();
    let (min, max) = pairs.iter().fold((u32::MAX, 0), |(lo, hi), &p| {
        (lo.min(key(p)), hi.max(key(p)))
    });
    let passes = (u32::BITS - (max - min).leading_zeros()).div_ceil(BITS) as usize;
    let mut hist = vec![[0u32; BUCKETS]; passes];
    let offset = pair(min, 0);
    for p in pairs.iter_mut() {
        *p -= offset;
        for (d, h) in hist.iter_mut().enumerate() {
            h[((*p >> (32 + d as u32 * BITS)) & MASK) as usize] += 1;
        }
    }
    let mut out = vec![0u64; n];
    for (d, offsets) in hist.iter_mut().enumerate() {
        if offsets.iter().any(|&c| c as usize == n) {
            continue;
        }
        let mut at = 0;
        for o in offsets.iter_mut() {
            (*o, at) = (at, at + *o);
        }
        let shift = 32 + d as u32 * BITS;
        for &p in &pairs {
            let slot = &mut offsets[((p >> shift) & MASK) as usize];
            out[*slot as usize] = p;
            *slot += 1;
        }
        std::mem::swap(&mut pairs, &mut out);
    }
    pairs.iter().map(|&p| p as u32).collect()
}

/// The output array of a scatter, written by many threads at disjoint positions.
#[derive(Clone, Copy)]
struct SharedOut(*mut u64);

// SAFETY: the pointer is only written through at positions that one thread alone owns
// (see the scatter), while the array it points into outlives the parallel pass.
unsafe impl Send for SharedOut {}
unsafe impl Sync for SharedOut {}

impl SharedOut {
    /// # Safety
    /// `i` is in bounds and no other thread reads or writes position `i` meanwhile.
    #[inline(always)]
    unsafe fn write(self, i: usize, v: u64) {
        // SAFETY: the caller's contract.
        unsafe { self.0.add(i).write(v) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::Lcg;
    use crate::threads::with_threads;

    #[test]
    fn radix_sort_matches_a_comparison_sort_on_any_thread_count() {
        let mut rng = Lcg::new(3);
        let mut next = move || rng.u31();
        for (n, spread) in [
            (0usize, 1u32),
            (1, 1),
            (1000, 7),
            (50_000, u32::MAX),
            (3000, 1 << 20),
            // Several chunks on 2 and 5 threads: many ties, and keys whose low digit is
            // constant (a skipped pass before a real one).
            (3 * MIN_CHUNK + 17, 5),
            (5 * MIN_CHUNK + 3, 1 << 30),
            (MAX_CHUNKS * MIN_CHUNK + 999, 1 << 24),
        ] {
            let low_constant = n == 5 * MIN_CHUNK + 3;
            let keys: Vec<u32> = (0..n)
                .map(|_| {
                    let k = next() % spread.max(1);
                    if low_constant {
                        k & !(MASK as u32)
                    } else {
                        k
                    }
                })
                .collect();
            let ids: Vec<u32> = (0..n as u32).map(|i| i * 3 + 1).collect();
            let mut sorted: Vec<(u32, u32)> =
                keys.iter().copied().zip(ids.iter().copied()).collect();
            sorted.sort();
            let want: Vec<u32> = sorted.into_iter().map(|(_, id)| id).collect();
            for threads in [1, 2, 5] {
                let pairs: Vec<u64> = keys.iter().zip(&ids).map(|(&k, &i)| pair(k, i)).collect();
                let got = with_threads(Some(threads), || Ok(radix_sort_pairs(pairs))).unwrap();
                assert_eq!(got, want, "n {n} spread {spread} threads {threads}");
            }
        }
    }

    #[test]
    fn depth_order_skips_hidden_splats_and_breaks_ties_by_index() {
        let at = |depth: f32, visible: bool| Splat {
            depth,
            radius: if visible { [2.0, 2.0] } else { [0.0, 0.0] },
            ..Splat::default()
        };
        let splats = [at(2.0, true), at(1.0, true), at(5.0, false), at(1.0, true)];
        assert!(splats[0].visible() && !splats[2].visible());
        assert_eq!(depth_order(&splats), vec![1, 3, 0]);
    }
}
