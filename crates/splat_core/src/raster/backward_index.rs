//! Each splat's intersections, together: the tile-major lists (`TileBins::isect_gid`)
//! inverted by a counting sort into a splat-major order (a splat's intersections in tile
//! order, splats in index order). The blend backward writes each intersection's gradients
//! at its splat-major row, so that the chain then reads every splat's rows in one
//! sequential pass, in parallel over splats and summed in the same order for any thread
//! count. Summing from the tile-major rows instead was bound by cache misses: a splat's
//! rows lie in different tiles' lists, far apart.

use crate::memory::{try_filled, try_vec};
use crate::CoreResult;

/// Splat-major rows of the intersections of one camera.
pub(super) struct SplatIntersections {
    /// Splat i's intersections are rows `start[i]..start[i + 1]`.
    start: Vec<u32>,
    /// `row[j]`: the row of intersection j (tile-major index).
    row: Vec<u32>,
}

impl SplatIntersections {
    /// `gids[j]` is the splat of intersection j; every gid is below `n`. Rows are u32 like
    /// the gids (4G intersections would take > 100 GiB of gradients).
    pub fn new(gids: &[u32], n: usize) -> CoreResult<Self> {
        let mut start = try_filled(n + 1, 0u32)?;
        for &g in gids {
            start[g as usize + 1] += 1;
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let mut next = start[..n].to_vec();
        let mut row = try_vec(gids.len())?;
        row.extend(gids.iter().map(|&g| {
            let at = &mut next[g as usize];
            *at += 1;
            *at - 1
        }));
        Ok(Self { start, row })
    }

    /// The rows of splats `i0..i1`.
    #[inline(always)]
    pub fn rows(&self, i0: usize, i1: usize) -> std::ops::Range<usize> {
        self.start[i0] as usize..self.start[i1] as usize
    }

    /// The rows of intersections `range` (tile-major indices).
    pub fn row_of(&self, range: std::ops::Range<usize>) -> &[u32] {
        &self.row[range]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::Lcg;

    #[test]
    fn rows_hold_each_splats_intersections_in_order() {
        let mut rng = Lcg::new(3);
        let n = 50;
        // Splat 7 has none; the others appear at random.
        let gids: Vec<u32> = (0..2000)
            .map(|_| rng.u31() % n as u32)
            .filter(|&g| g != 7)
            .collect();
        let idx = SplatIntersections::new(&gids, n).unwrap();
        let rows = idx.row_of(0..gids.len());
        // Row r holds intersection j: listing splat i's rows gives its intersections in
        // increasing order.
        let mut at = vec![usize::MAX; gids.len()];
        for (j, &r) in rows.iter().enumerate() {
            assert_eq!(at[r as usize], usize::MAX, "row {r} used twice");
            at[r as usize] = j;
        }
        for i in 0..n {
            let want: Vec<usize> = (0..gids.len()).filter(|&j| gids[j] as usize == i).collect();
            let got: Vec<usize> = idx.rows(i, i + 1).map(|r| at[r]).collect();
            assert_eq!(got, want, "splat {i}");
        }
        assert!(idx.rows(7, 8).is_empty());
        assert_eq!(idx.rows(0, n), 0..gids.len());
        assert!(SplatIntersections::new(&[], 3)
            .unwrap()
            .rows(0, 3)
            .is_empty());
    }
}
