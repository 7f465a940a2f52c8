//! Visible splats in depth order: a parallel, stable LSD radix sort of (depth, index) words.
//!
//! The work is cut into chunks of the input. Each pass counts its digit per chunk in
//! parallel, turns the counts into output offsets (digit-major, chunk order within a digit)
//! and scatters every chunk in parallel to its own offsets. Chunk c's elements of a digit
//! land after those of chunks before it and in their input order, so each pass is the
//! stable counting sort a single thread would do. The words are distinct (the index is in
//! them), so their sorted order is unique: the chunking, which follows the thread count,
//! cannot change the result, and one thread runs the sequential sort with no chunks.
//!
//! On several threads the splats are read once: each chunk collects its visible words,
//! their key range and the first pass's digit counts, and the first pass scatters from
//! the chunks' own vectors (no concatenation). Only the bits above which the smallest and
//! largest keys agree are sorted (the keys agree on the rest), and the last pass writes
//! the ids rather than words to be narrowed after.
#![allow(unsafe_code)]

use rayon::prelude::*;

use super::project::Splat;

/// Bits per digit: a 16 KiB histogram, in L1. Depths of one scene span a few binades, so
/// their bit patterns differ in the low 24-26 bits and two or three passes cover them.
const BITS: u32 = 12;
const MASK: u64 = (1 << BITS) - 1;
const BUCKETS: usize = 1 << BITS;
/// Elements per chunk at least (smaller inputs are one chunk: the offsets cost
/// `BUCKETS` per chunk and pass), chunks per thread (for balance), and chunks at most.
const MIN_CHUNK: usize = 16_384;
const CHUNKS_PER_THREAD: usize = 4;
const MAX_CHUNKS: usize = 64;

type Histogram = [u32; BUCKETS];

/// Visible splats ordered front to back; ties broken by index, so the order is unique.
pub fn depth_order(splats: &[Splat]) -> Vec<u32> {
    // Depths of visible splats are >= near_plane > 0, so their bit patterns sort like the
    // values. Collected in index order, a stable sort by depth breaks ties by index.
    let chunk = chunk_len(splats.len());
    if chunk >= splats.len() || rayon::current_num_threads() == 1 {
        let visible =
            |(g, s): (usize, &Splat)| s.visible().then_some(pair(s.depth.to_bits(), g as u32));
        return sort_on_one_thread(splats.iter().enumerate().filter_map(visible).collect());
    }
    let parts: Vec<(Vec<u64>, Histogram, u32, u32)> = splats
        .par_chunks(chunk)
        .enumerate()
        .map(|(ci, c)| {
            let mut words = Vec::with_capacity(c.len());
            let mut h = [0u32; BUCKETS];
            let (mut lo, mut hi) = (u32::MAX, 0);
            for (j, s) in c.iter().enumerate() {
                if s.visible() {
                    let k = s.depth.to_bits();
                    (lo, hi) = (lo.min(k), hi.max(k));
                    let p = pair(k, (ci * chunk + j) as u32);
                    h[digit(p, 0)] += 1;
                    words.push(p);
                }
            }
            (words, h, lo, hi)
        })
        .collect();
    let lo = parts.iter().map(|p| p.2).min().unwrap_or(u32::MAX);
    let hi = parts.iter().map(|p| p.3).max().unwrap_or(0);
    let sources: Vec<&[u64]> = parts.iter().map(|p| p.0.as_slice()).collect();
    let first = parts.iter().map(|p| p.1).collect();
    sort_passes(&sources, first, passes_for(lo, hi))
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

/// Pass `d`'s digit of a word.
#[inline(always)]
fn digit(p: u64, d: u32) -> usize {
    ((p >> (32 + d * BITS)) & MASK) as usize
}

/// Passes that sort keys in [lo, hi]: those below the highest bit in which they differ
/// (every key in the range has the bits above it). 0 for no keys or one key value.
fn passes_for(lo: u32, hi: u32) -> u32 {
    if lo > hi {
        return 0;
    }
    (u32::BITS - (lo ^ hi).leading_zeros()).div_ceil(BITS)
}

/// Elements per chunk for `n` elements on the current pool.
fn chunk_len(n: usize) -> usize {
    let chunks = (CHUNKS_PER_THREAD * rayon::current_num_threads()).min(MAX_CHUNKS);
    n.div_ceil(chunks).max(MIN_CHUNK)
}

/// Pass `d`'s digit counts of one chunk.
fn histogram(words: &[u64], d: u32) -> Histogram {
    let mut h = [0u32; BUCKETS];
    for &p in words {
        h[digit(p, d)] += 1;
    }
    h
}

/// Counts to offsets: digit-major, chunk order within a digit.
fn prefix(offsets: &mut [Histogram]) {
    let mut at = 0u32;
    for b in 0..BUCKETS {
        for h in offsets.iter_mut() {
            (h[b], at) = (at, at + h[b]);
        }
    }
}

/// Stable LSD radix sort of (key, id) `pair`s by key on the current pool; returns the ids.
/// (The sort of `depth_order` on words already collected, for the tests.)
#[cfg(test)]
pub(super) fn radix_sort_pairs(pairs: Vec<u64>) -> Vec<u32> {
    let chunk = chunk_len(pairs.len());
    if chunk >= pairs.len() || rayon::current_num_threads() == 1 {
        return sort_on_one_thread(pairs);
    }
    let lo = pairs.iter().map(|&p| key(p)).min().unwrap_or(u32::MAX);
    let hi = pairs.iter().map(|&p| key(p)).max().unwrap_or(0);
    let sources: Vec<&[u64]> = pairs.chunks(chunk).collect();
    let first = sources.iter().map(|c| histogram(c, 0)).collect();
    sort_passes(&sources, first, passes_for(lo, hi))
}

/// The passes of the parallel sort. The first scatters `sources` (the words in chunks, in
/// order) with their digit counts `first`; later passes count on fixed-size chunks. The
/// top pass always moves something (the smallest and largest keys differ in its digit)
/// and writes the ids; a pass below it whose digit is the same for every word is skipped.
fn sort_passes(sources: &[&[u64]], mut first: Vec<Histogram>, passes: u32) -> Vec<u32> {
    let n: usize = sources.iter().map(|s| s.len()).sum();
    if passes == 0 {
        // One key value (or none): index order, which is the chunks' order.
        return sources
            .iter()
            .flat_map(|s| s.iter().map(|&p| p as u32))
            .collect();
    }
    prefix(&mut first);
    if passes == 1 {
        let mut ids = vec![0u32; n];
        scatter(sources, &mut first, 0, &mut ids, |p| p as u32);
        return ids;
    }
    let mut words = vec![0u64; n];
    scatter(sources, &mut first, 0, &mut words, |p| p);
    let mut spare = vec![0u64; n];
    let chunk = chunk_len(n);
    for d in 1..passes {
        let chunks: Vec<&[u64]> = words.chunks(chunk).collect();
        let mut offsets: Vec<Histogram> = chunks.par_iter().map(|c| histogram(c, d)).collect();
        let lead = digit(words[0], d);
        let top = d + 1 == passes;
        if !top && offsets.iter().map(|h| h[lead] as usize).sum::<usize>() == n {
            continue;
        }
        prefix(&mut offsets);
        if top {
            let mut ids = vec![0u32; n];
            scatter(&chunks, &mut offsets, d, &mut ids, |p| p as u32);
            return ids;
        }
        scatter(&chunks, &mut offsets, d, &mut spare, |p| p);
        drop(chunks);
        std::mem::swap(&mut words, &mut spare);
    }
    unreachable!("the top pass returns")
}

/// One pass's scatter: every chunk of `sources` writes `f(word)` at its offsets of the
/// word's digit, in parallel.
fn scatter<T: Copy + Send + Sync>(
    sources: &[&[u64]],
    offsets: &mut [Histogram],
    d: u32,
    out: &mut [T],
    f: impl Fn(u64) -> T + Sync,
) {
    let n = out.len();
    let dst = Shared(out.as_mut_ptr());
    sources
        .par_iter()
        .zip(offsets.par_iter_mut())
        .for_each(|(src, slots)| {
            for &p in *src {
                let slot = &mut slots[digit(p, d)];
                debug_assert!((*slot as usize) < n);
                // SAFETY: the offsets give every (chunk, digit) its own range of `out`, of
                // exactly the chunk's count of that digit, and the ranges tile 0..n; each
                // chunk writes only its own ranges, once per slot, so no two writes alias
                // and all stay in bounds (n = out.len()).
                unsafe { dst.write(*slot as usize, f(p)) };
                *slot += 1;
            }
        });
}

/// `radix_sort_pairs` on the calling thread: the key range in one read, every pass's
/// histogram in one more, then the passes; the last one that moves anything writes ids.
fn sort_on_one_thread(mut pairs: Vec<u64>) -> Vec<u32> {
    let n = pairs.len();
    if n == 0 {
        return Vec::new();
    }
    let (min, max) = pairs.iter().fold((u32::MAX, 0), |(lo, hi), &p| {
        (lo.min(key(p)), hi.max(key(p)))
    });
    let passes = passes_for(0, max - min) as usize;
    let mut hist = vec![[0u32; BUCKETS]; passes];
    let offset = pair(min, 0);
    for p in pairs.iter_mut() {
        *p -= offset;
        for (d, h) in hist.iter_mut().enumerate() {
            h[digit(*p, d as u32)] += 1;
        }
    }
    let moving: Vec<usize> = (0..passes)
        .filter(|&d| hist[d].iter().all(|&c| c as usize != n))
        .collect();
    let mut out = vec![0u64; if moving.len() > 1 { n } else { 0 }];
    for (i, &d) in moving.iter().enumerate() {
        let offsets = &mut hist[d];
        let mut at = 0;
        for o in offsets.iter_mut() {
            (*o, at) = (at, at + *o);
        }
        if i + 1 == moving.len() {
            let mut ids = vec![0u32; n];
            for &p in &pairs {
                let slot = &mut offsets[digit(p, d as u32)];
                ids[*slot as usize] = p as u32;
                *slot += 1;
            }
            return ids;
        }
        for &p in &pairs {
            let slot = &mut offsets[digit(p, d as u32)];
            out[*slot as usize] = p;
            *slot += 1;
        }
        std::mem::swap(&mut pairs, &mut out);
    }
    pairs.iter().map(|&p| p as u32).collect()
}

/// The output array of a scatter, written by many threads at disjoint positions.
struct Shared<T>(*mut T);

impl<T> Clone for Shared<T> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<T> Copy for Shared<T> {}

// SAFETY: the pointer is only written through at positions that one thread alone owns
// (see `scatter`), while the array it points into outlives the parallel pass.
unsafe impl<T: Send> Send for Shared<T> {}
unsafe impl<T: Send> Sync for Shared<T> {}

impl<T> Shared<T> {
    /// # Safety
    /// `i` is in bounds and no other thread reads or writes position `i` meanwhile.
    #[inline(always)]
    unsafe fn write(self, i: usize, v: T) {
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
    fn depth_order_is_a_comparison_sort_of_the_visible_on_any_thread_count() {
        let mut rng = Lcg::new(11);
        // Several chunks on 2 and 5 threads; depths with ties, a few binades apart (two or
        // three passes), a third of the splats hidden, and one chunk with none visible.
        for (n, spread) in [(5 * MIN_CHUNK + 17, 1u32 << 26), (3 * MIN_CHUNK + 5, 7)] {
            let splats: Vec<Splat> = (0..n)
                .map(|i| {
                    let hidden =
                        rng.u31().is_multiple_of(3) || (MIN_CHUNK..2 * MIN_CHUNK).contains(&i);
                    let depth = f32::from_bits(1.0f32.to_bits() + rng.u31() % spread);
                    Splat {
                        depth,
                        radius: if hidden { [0.0, 0.0] } else { [1.0, 3.0] },
                        ..Splat::default()
                    }
                })
                .collect();
            let mut want: Vec<(u32, u32)> = (0..n)
                .filter(|&i| splats[i].visible())
                .map(|i| (splats[i].depth.to_bits(), i as u32))
                .collect();
            want.sort();
            let want: Vec<u32> = want.into_iter().map(|(_, i)| i).collect();
            for threads in [1, 2, 5] {
                let got = with_threads(Some(threads), || Ok(depth_order(&splats))).unwrap();
                assert_eq!(got, want, "n {n} threads {threads}");
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
