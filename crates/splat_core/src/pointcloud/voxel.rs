//! Voxel grid downsampling with Open3D 0.20's legacy semantics, and a search for the voxel
//! size that gives a target point count.
//!
//! Open3D (`PointCloud::VoxelDownSample`): origin = min_bound - voxel/2, voxel index =
//! floor((p - origin) / voxel) per axis (f64), each occupied voxel becomes the mean of its
//! points (and of their colours), summed in input order and divided by the count. Open3D
//! returns voxels in hash-map order; we return them sorted by (ix, iy, iz), which makes the
//! output deterministic. Open3D refuses grids whose index would overflow an i32; so do we.

use std::collections::{HashMap, HashSet};
use std::hash::{BuildHasherDefault, Hash, Hasher};

use rayon::prelude::*;

use super::{check_points, point, Coord};
use crate::{CoreError, CoreResult};

struct Grid {
    origin: [f64; 3],
    size: f64,
    /// Bits per axis of the packed key (x highest).
    bits: [u32; 3],
}

impl Grid {
    fn new<T: Coord>(points: &[T], n: usize, voxel_size: f64) -> CoreResult<Self> {
        if !(voxel_size.is_finite() && voxel_size > 0.0) {
            return Err(CoreError::input(format!(
                "voxel_size must be a positive number, got {voxel_size}"
            )));
        }
        let (lo, hi) = (0..n)
            .into_par_iter()
            .with_min_len(4096)
            .map(|i| {
                let p = point(points, i);
                (p, p)
            })
            .reduce(
                || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
                |(a0, a1), (b0, b1)| {
                    (
                        [a0[0].min(b0[0]), a0[1].min(b0[1]), a0[2].min(b0[2])],
                        [a1[0].max(b1[0]), a1[1].max(b1[1]), a1[2].max(b1[2])],
                    )
                },
            );
        let half = voxel_size * 0.5;
        let origin = [lo[0] - half, lo[1] - half, lo[2] - half];
        let extent = (0..3)
            .map(|a| (hi[a] + half) - origin[a])
            .fold(0.0, f64::max);
        if voxel_size * f64::from(i32::MAX) < extent {
            return Err(CoreError::input(format!(
                "voxel_size {voxel_size} is too small for a cloud {extent} across: \
                 the voxel index would overflow"
            )));
        }
        let mut grid = Self {
            origin,
            size: voxel_size,
            bits: [0; 3],
        };
        // The largest index per axis is the one of the max bound (the map is monotone).
        grid.bits = grid.index(&hi).map(|top| 64 - top.leading_zeros());
        Ok(grid)
    }

    #[inline]
    fn index(&self, p: &[f64; 3]) -> [u64; 3] {
        let mut out = [0u64; 3];
        for a in 0..3 {
            // r >= 0 (p >= min bound > origin), so truncation is floor; `f64::floor` is a
            // libm call on baseline x86-64 and dominated the whole kernel.
            let r = (p[a] - self.origin[a]) / self.size;
            out[a] = r as u64;
        }
        out
    }

    #[inline]
    fn key128(&self, p: &[f64; 3]) -> u128 {
        let i = self.index(p);
        (u128::from(i[0]) << (self.bits[1] + self.bits[2]))
            | (u128::from(i[1]) << self.bits[2])
            | u128::from(i[2])
    }

    /// The packed key when `fits_u64` (u64 shifts are much cheaper than u128 ones).
    #[inline]
    fn key64(&self, p: &[f64; 3]) -> u64 {
        let i = self.index(p);
        (i[0] << (self.bits[1] + self.bits[2])) | (i[1] << self.bits[2]) | i[2]
    }

    fn fits_u64(&self) -> bool {
        self.bits.iter().sum::<u32>() <= 64
    }
}

/// Multiplicative hashing of voxel keys (std's SipHash is several times slower here).
/// The high half is folded into the low bits, which hashbrown uses for the bucket index.
#[derive(Default, Clone, Copy)]
struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    #[inline]
    fn write_u64(&mut self, v: u64) {
        let h = (self.0.rotate_left(23) ^ v).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        self.0 = h ^ (h >> 29);
    }

    #[inline]
    fn write_u128(&mut self, v: u128) {
        self.write_u64(v as u64);
        self.write_u64((v >> 64) as u64);
    }
}

type KeyMap<K, V> = HashMap<K, V, BuildHasherDefault<KeyHasher>>;

trait VoxelKey: Hash + Eq + Ord + Copy + Send + Sync {
    fn of(grid: &Grid, p: &[f64; 3]) -> Self;
    /// Which of `parts` workers owns this voxel (a hash independent of the map's).
    fn part(self, parts: usize) -> usize;
}

impl VoxelKey for u64 {
    #[inline]
    fn of(grid: &Grid, p: &[f64; 3]) -> Self {
        grid.key64(p)
    }
    #[inline]
    fn part(self, parts: usize) -> usize {
        // Multiply-shift range reduction: a `%` by a runtime value costs ~30 cycles.
        (((self.wrapping_mul(0xD6E8_FEB8_6659_FD93) >> 32) * parts as u64) >> 32) as usize
    }
}

impl VoxelKey for u128 {
    #[inline]
    fn of(grid: &Grid, p: &[f64; 3]) -> Self {
        grid.key128(p)
    }
    #[inline]
    fn part(self, parts: usize) -> usize {
        ((self as u64) ^ ((self >> 64) as u64).rotate_left(17)).part(parts)
    }
}

/// Voxel key and owning worker of every point (two arrays: the owner scan stays small).
fn keys<T: Coord, K: VoxelKey>(
    points: &[T],
    n: usize,
    grid: &Grid,
    parts: usize,
) -> (Vec<K>, Vec<u8>) {
    let mut keys = Vec::with_capacity(n);
    let mut owners = Vec::with_capacity(n);
    (0..n)
        .into_par_iter()
        .with_min_len(4096)
        .map(|i| {
            let k = K::of(grid, &point(points, i));
            (k, k.part(parts) as u8)
        })
        .unzip_into_vecs(&mut keys, &mut owners);
    (keys, owners)
}

/// Number of workers: the pool size, capped so a worker id fits a byte. The output does
/// not depend on it (each voxel is summed by one worker, in input order).
fn parts() -> usize {
    rayon::current_num_threads().clamp(1, 64)
}

/// The voxel means, in key order.
#[derive(Debug, Clone, PartialEq)]
pub struct VoxelOutput {
    /// Flat xyz means (f64; cast to the input precision by the caller).
    pub points: Vec<f64>,
    /// Flat rgb means, if colours were given.
    pub colors: Option<Vec<f32>>,
}

/// The points one worker owns, ascending.
enum Owned {
    All(usize),
    Some(Vec<u32>),
}

impl Owned {
    fn indices(&self) -> Box<dyn Iterator<Item = usize> + '_> {
        match self {
            Owned::All(n) => Box::new(0..*n),
            Owned::Some(v) => Box::new(v.iter().map(|&i| i as usize)),
        }
    }
}

/// Splits point indices by owner (one sequential pass, so each list is ascending); workers
/// then touch only their own points instead of testing every owner byte.
fn by_owner(owners: &[u8], parts: usize) -> Vec<Owned> {
    if parts == 1 {
        return vec![Owned::All(owners.len())];
    }
    let mut lists = vec![Vec::with_capacity(owners.len() / parts + 16); parts];
    for (i, &o) in owners.iter().enumerate() {
        lists[o as usize].push(i as u32);
    }
    lists.into_iter().map(Owned::Some).collect()
}

#[derive(Clone, Copy)]
struct Acc {
    sum: [f64; 3],
    color: [f64; 3],
    count: u32,
}

fn grouped<T: Coord, K: VoxelKey>(
    points: &[T],
    colors: Option<&[f32]>,
    n: usize,
    grid: &Grid,
) -> VoxelOutput {
    let parts = parts();
    let (keys, owners) = keys::<T, K>(points, n, grid, parts);
    let lists = by_owner(&owners, parts);
    let mut voxels: Vec<(K, Acc)> = lists
        .par_iter()
        .flat_map_iter(|list| {
            // One map per worker; each voxel's points are added in input order.
            let mut map: KeyMap<K, Acc> = KeyMap::default();
            let zero = Acc {
                sum: [0.0; 3],
                color: [0.0; 3],
                count: 0,
            };
            for i in list.indices() {
                let v = map.entry(keys[i]).or_insert(zero);
                let p = point(points, i);
                v.sum = [v.sum[0] + p[0], v.sum[1] + p[1], v.sum[2] + p[2]];
                if let Some(c) = colors {
                    for a in 0..3 {
                        v.color[a] += f64::from(c[3 * i + a]);
                    }
                }
                v.count += 1;
            }
            map.into_iter()
        })
        .collect();
    voxels.par_sort_unstable_by_key(|v| v.0);
    let pts = voxels
        .iter()
        .flat_map(|(_, v)| {
            let c = f64::from(v.count);
            [v.sum[0] / c, v.sum[1] / c, v.sum[2] / c]
        })
        .collect();
    let colors = colors.map(|_| {
        voxels
            .iter()
            .flat_map(|(_, v)| {
                let c = f64::from(v.count);
                [
                    (v.color[0] / c) as f32,
                    (v.color[1] / c) as f32,
                    (v.color[2] / c) as f32,
                ]
            })
            .collect()
    });
    VoxelOutput {
        points: pts,
        colors,
    }
}

/// Voxel grid downsampling (Open3D legacy semantics, output sorted by voxel index).
pub fn voxel_downsample<T: Coord>(
    points: &[T],
    voxel_size: f64,
    colors: Option<&[f32]>,
) -> CoreResult<VoxelOutput> {
    let n = check_points(points)?;
    if let Some(c) = colors {
        crate::error::check_len("colors", c, n, 3)?;
    }
    let grid = Grid::new(points, n, voxel_size)?;
    Ok(if grid.fits_u64() {
        grouped::<T, u64>(points, colors, n, &grid)
    } else {
        grouped::<T, u128>(points, colors, n, &grid)
    })
}

fn distinct<T: Coord, K: VoxelKey>(points: &[T], n: usize, grid: &Grid) -> usize {
    let parts = parts();
    let (keys, owners) = keys::<T, K>(points, n, grid, parts);
    by_owner(&owners, parts)
        .par_iter()
        .map(|list| {
            let mut set: HashSet<K, BuildHasherDefault<KeyHasher>> = HashSet::default();
            set.extend(list.indices().map(|i| keys[i]));
            set.len()
        })
        .sum()
}

/// Number of occupied voxels (the output size of `voxel_downsample`).
pub fn voxel_count<T: Coord>(points: &[T], voxel_size: f64) -> CoreResult<usize> {
    let n = check_points(points)?;
    let grid = Grid::new(points, n, voxel_size)?;
    Ok(if grid.fits_u64() {
        distinct::<T, u64>(points, n, &grid)
    } else {
        distinct::<T, u128>(points, n, &grid)
    })
}

/// Result of `downsample_to_count`.
#[derive(Debug, Clone, PartialEq)]
pub struct CountDownsample {
    pub output: VoxelOutput,
    /// The voxel size used; 0.0 when the input was already small enough (returned as is).
    pub voxel_size: f64,
}

/// Voxel-downsamples to `target` points within +-`tolerance` (relative), by bisection on
/// the (log) voxel size. Inputs with at most target * (1 + tolerance) points are returned
/// unchanged. The count is not perfectly monotone in the voxel size; if no size within
/// 64 bisection steps lands in the band (clouds made of a few heavy clusters), this is an
/// InputError naming the closest count reached.
pub fn downsample_to_count<T: Coord>(
    points: &[T],
    target: usize,
    colors: Option<&[f32]>,
    tolerance: f64,
) -> CoreResult<CountDownsample> {
    let n = check_points(points)?;
    if let Some(c) = colors {
        crate::error::check_len("colors", c, n, 3)?;
    }
    if target == 0 {
        return Err(CoreError::input("target must be at least 1"));
    }
    if !(tolerance.is_finite() && (0.0..1.0).contains(&tolerance)) {
        return Err(CoreError::input(format!(
            "tolerance must be in [0, 1), got {tolerance}"
        )));
    }
    let lower = (target as f64 * (1.0 - tolerance)).ceil() as usize;
    let upper = (target as f64 * (1.0 + tolerance)).floor() as usize;
    if n <= upper {
        let output = VoxelOutput {
            points: points.iter().map(|v| v.to_f64()).collect(),
            colors: colors.map(<[f32]>::to_vec),
        };
        return Ok(CountDownsample {
            output,
            voxel_size: 0.0,
        });
    }
    if lower > upper {
        return Err(CoreError::input(format!(
            "target {target} with tolerance {tolerance} allows no whole count"
        )));
    }
    let extent = {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for i in 0..n {
            let p = point(points, i);
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max)
    };
    if extent == 0.0 {
        return Err(CoreError::input(format!(
            "all {n} points are identical: no voxel size gives {target} points"
        )));
    }
    // Bracket in log space: `small` gives too many voxels, `big` too few.
    let (mut small, mut big) = ((extent * 1e-7).ln(), (extent * 2.0).ln());
    let mut best = (usize::MAX, 0usize, 0.0f64);
    let consider = |best: &mut (usize, usize, f64), v: f64, count: usize| {
        let miss = count.abs_diff(target);
        if miss < best.0 {
            *best = (miss, count, v);
        }
    };
    let count_small = voxel_count(points, small.exp())?;
    consider(&mut best, small.exp(), count_small);
    if count_small < lower {
        return Err(CoreError::input(format!(
            "only {count_small} distinct voxels even at voxel size {:.3e}: the cloud has too few \
             distinct points for target {target}",
            small.exp()
        )));
    }
    for _ in 0..64 {
        if (lower..=upper).contains(&best.1) {
            break;
        }
        let mid = 0.5 * (small + big);
        let count = voxel_count(points, mid.exp())?;
        consider(&mut best, mid.exp(), count);
        if count > upper {
            small = mid;
        } else if count < lower {
            big = mid;
        } else {
            break;
        }
    }
    let (_, count, voxel_size) = best;
    if !(lower..=upper).contains(&count) {
        return Err(CoreError::input(format!(
            "no voxel size gives {target} +- {:.0}% points; the closest is {count} at voxel size {voxel_size:.6e}",
            tolerance * 100.0
        )));
    }
    Ok(CountDownsample {
        output: voxel_downsample(points, voxel_size, colors)?,
        voxel_size,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::Lcg;
    use crate::threads::with_threads;
    use std::collections::BTreeMap;

    fn cloud(n: usize) -> (Vec<f32>, Vec<f32>) {
        let mut rng = Lcg::new(99);
        let mut rnd = move || rng.uniform();
        let pts = (0..3 * n).map(|_| rnd() * 2.0 - 0.5).collect();
        let cols = (0..3 * n).map(|_| rnd()).collect();
        (pts, cols)
    }

    /// BTreeMap reference: the same arithmetic, sequential.
    fn reference(pts: &[f32], cols: &[f32], v: f64) -> (Vec<f64>, Vec<f32>) {
        let n = pts.len() / 3;
        let mut lo = [f64::INFINITY; 3];
        for i in 0..n {
            for a in 0..3 {
                lo[a] = lo[a].min(f64::from(pts[3 * i + a]));
            }
        }
        let origin: Vec<f64> = lo.iter().map(|l| l - v * 0.5).collect();
        let mut map: BTreeMap<[i64; 3], (Vec<f64>, Vec<f64>, f64)> = BTreeMap::new();
        for i in 0..n {
            let key =
                [0, 1, 2].map(|a| ((f64::from(pts[3 * i + a]) - origin[a]) / v).floor() as i64);
            let e = map.entry(key).or_insert((vec![0.0; 3], vec![0.0; 3], 0.0));
            for a in 0..3 {
                e.0[a] += f64::from(pts[3 * i + a]);
                e.1[a] += f64::from(cols[3 * i + a]);
            }
            e.2 += 1.0;
        }
        let mut p = Vec::new();
        let mut c = Vec::new();
        for (_, (s, cs, k)) in map {
            p.extend(s.iter().map(|x| x / k));
            c.extend(cs.iter().map(|x| (x / k) as f32));
        }
        (p, c)
    }

    #[test]
    fn matches_reference_bit_for_bit() {
        let (pts, cols) = cloud(20_000);
        for v in [0.05, 0.173, 1.0, 10.0] {
            let out = voxel_downsample(&pts, v, Some(&cols)).unwrap();
            let (p, c) = reference(&pts, &cols, v);
            assert_eq!(out.points, p, "voxel {v}");
            assert_eq!(out.colors.unwrap(), c);
            assert_eq!(voxel_count(&pts, v).unwrap(), p.len() / 3);
        }
    }

    #[test]
    fn wide_grids_use_wide_keys() {
        let pts = [0.0f64, 0.0, 0.0, 1e6, 1e6, 1e6, 1e6, 0.0, 1.0];
        let out = voxel_downsample(&pts, 1e-3, None).unwrap();
        assert_eq!(
            out.points,
            vec![0.0, 0.0, 0.0, 1e6, 0.0, 1.0, 1e6, 1e6, 1e6]
        );
    }

    #[test]
    fn bad_voxel_sizes_and_overflow() {
        let (pts, _) = cloud(100);
        for v in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                voxel_downsample(&pts, v, None),
                Err(CoreError::Input(_))
            ));
        }
        let err = voxel_downsample(&pts, 1e-12, None).unwrap_err().to_string();
        assert!(err.contains("overflow"), "{err}");
        assert!(matches!(
            voxel_downsample(&pts, 0.1, Some(&[0.0; 5])),
            Err(CoreError::Input(_))
        ));
    }

    #[test]
    fn count_search_lands_in_band_and_is_thread_independent() {
        let (pts, cols) = cloud(50_000);
        for target in [1000, 5000, 20_000] {
            let r = downsample_to_count(&pts, target, Some(&cols), 0.05).unwrap();
            let m = r.output.points.len() / 3;
            assert!(
                m.abs_diff(target) as f64 <= 0.05 * target as f64,
                "{target}: {m}"
            );
        }
        let a = with_threads(Some(1), || downsample_to_count(&pts, 3000, None, 0.05)).unwrap();
        let b = with_threads(Some(2), || downsample_to_count(&pts, 3000, None, 0.05)).unwrap();
        assert_eq!(a.output.points, b.output.points);
        let same = downsample_to_count(&pts, 60_000, None, 0.05).unwrap();
        assert_eq!(same.voxel_size, 0.0);
        assert_eq!(same.output.points.len(), pts.len());
    }

    #[test]
    fn count_search_reports_impossible_targets() {
        let pts = [1.0f32, 2.0, 3.0].repeat(5000);
        assert!(matches!(
            downsample_to_count(&pts, 10, None, 0.05),
            Err(CoreError::Input(_))
        ));
        let mut two = [0.0f32; 3].repeat(3000);
        two.extend([1.0f32; 3].repeat(3000));
        let err = downsample_to_count(&two, 100, None, 0.05)
            .unwrap_err()
            .to_string();
        assert!(err.contains("distinct"), "{err}");
    }
}
