//! Times the kd-tree build, SOR (k = 20) and the voxel grid on 1M points of a noisy shell,
//! without Python in the way (for profiling the kernels; the comparison with Open3D is
//! benches/bench_pointcloud.py):
//!
//!     cargo run --release -p splat_core --example pointcloud_timing -- [THREADS]
use std::time::Instant;

use splat_core::pointcloud::{remove_statistical_outliers, voxel_downsample, KdTree};
use splat_core::threads::with_threads;

fn main() {
    let threads = std::env::args().nth(1).and_then(|a| a.parse().ok());
    let n = 1_000_000;
    let mut s = 1u64;
    let mut rnd = move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 40) as f64 / (1u64 << 24) as f64
    };
    let mut pts = Vec::with_capacity(3 * n);
    for _ in 0..n {
        let (u, v) = (rnd() * std::f64::consts::TAU, rnd() * 2.0 - 1.0);
        let r = (1.0 - v * v).sqrt();
        pts.extend([
            (0.3 * r * u.cos()) as f32,
            (0.2 * r * u.sin()) as f32,
            0.5 * v as f32,
        ]);
    }
    let colors: Vec<f32> = (0..3 * n).map(|_| rnd() as f32).collect();
    with_threads(threads, || {
        let t = Instant::now();
        let tree = KdTree::build(&pts);
        println!(
            "kd-tree build   {:.3} s ({} points)",
            t.elapsed().as_secs_f64(),
            tree.len()
        );
        let t = Instant::now();
        let kept = remove_statistical_outliers(&pts, 20, 2.0)?;
        println!(
            "SOR k=20        {:.3} s ({} kept)",
            t.elapsed().as_secs_f64(),
            kept.len()
        );
        let t = Instant::now();
        let out = voxel_downsample(&pts, 0.01, Some(&colors))?;
        let m = out.points.len() / 3;
        println!(
            "voxel 0.01      {:.3} s ({m} voxels)",
            t.elapsed().as_secs_f64()
        );
        Ok(())
    })
    .unwrap_or_else(|e| eprintln!("error: {e}"));
}
