//! Times the voxel grid on 1M random shell points: `cargo run --release --example voxel_timing`.
use splat_core::pointcloud::{voxel_count, voxel_downsample};

fn main() {
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
    for _ in 0..5 {
        let t = std::time::Instant::now();
        let out = voxel_downsample(&pts, 0.01, Some(&colors)).unwrap();
        let a = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let m = voxel_count(&pts, 0.01).unwrap();
        let b = t.elapsed().as_secs_f64();
        println!(
            "downsample {:.4} s ({} voxels), count {b:.4} s ({m})",
            a,
            out.points.len() / 3
        );
    }
}
