//! Times SOR (k = 20) on a synthetic 1M-point shell: `cargo run --release --example knn_timing`.
use splat_core::pointcloud::remove_statistical_outliers;
use splat_core::threads::with_threads;

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
        pts.extend([(r * u.cos()) as f32, (r * u.sin()) as f32, v as f32]);
    }
    let which: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(1);
    let t = std::time::Instant::now();
    let tree = splat_core::pointcloud::KdTree::build(&pts);
    println!("build {:.3} s", t.elapsed().as_secs_f64());
    let t = std::time::Instant::now();
    let v = tree.map_knn(19, |_, nb| nb.squared_distances()[18]);
    println!("queries {:.3} s {}", t.elapsed().as_secs_f64(), v.len());
    for threads in [which] {
        let t = std::time::Instant::now();
        let kept =
            with_threads(Some(threads), || remove_statistical_outliers(&pts, 20, 2.0)).unwrap();
        println!(
            "threads {threads}: {:.3} s, kept {}",
            t.elapsed().as_secs_f64(),
            kept.len()
        );
    }
}
