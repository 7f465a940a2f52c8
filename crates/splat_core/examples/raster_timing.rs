//! Times the forward rasterizer per stage on a scene dumped by
//! `python benches/raster_scene.py --dump FILE [--n N] [--size S]`, without Python in the
//! way (for profiling with perf):
//!
//!     cargo run --release -p splat_core --example raster_timing -- FILE [THREADS] [REPS]
//!
//! Prints the min and median of the calls, whole and per stage. `TILE=16` sets the tile
//! size (default: the core's); `BACKWARD=1` also times the backward pass; `HASH=1` prints
//! hashes of the image and gradient bits; `EVALS=1` also counts the blending work
//! (`raster::count_evaluations`, outside the timed calls; `benches/bench_roofline.py`
//! divides it by the times).
use std::time::Instant;

#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

use splat_core::raster::{self, Camera, ColorMode, Profile, RasterOptions, Scene};
use splat_core::threads::with_threads;

/// FNV-1a over the bits of the values: equal hashes, equal outputs (to check that a kernel
/// change keeps images and gradients bit for bit).
fn bits_hash<'a>(values: impl IntoIterator<Item = &'a f32>) -> u64 {
    values.into_iter().fold(0xcbf2_9ce4_8422_2325, |h, v| {
        (h ^ v.to_bits() as u64).wrapping_mul(0x100_0000_01b3)
    })
}

/// CPU time of every thread of the process so far, in seconds (Linux schedstat; 0
/// elsewhere). On a shared machine it leaves out the time other work holds the cores.
fn cpu_seconds() -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return 0.0;
    };
    let ns: u64 = tasks
        .flatten()
        .filter_map(|t| std::fs::read_to_string(t.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .sum();
    ns as f64 * 1e-9
}

/// Min and median of the calls, in seconds.
fn min_median(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[0], v[v.len() / 2])
}

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .expect("usage: raster_timing FILE [THREADS] [REPS]");
    let threads: usize = args.next().map_or(1, |a| a.parse().unwrap());
    let reps: usize = args.next().map_or(20, |a| a.parse().unwrap());
    let bytes = std::fs::read(&path).expect("cannot read the scene file");
    let v: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    let (n, size) = (v[0] as usize, v[1] as u32);
    let mut at = 2;
    let mut take = |len: usize| {
        at += len;
        &v[at - len..at]
    };
    let (m, q, s, o, c) = (take(3 * n), take(4 * n), take(3 * n), take(n), take(3 * n));
    let (vm, k) = (take(16), take(9));
    let scene = Scene::new(m, q, s, o, c, ColorMode::Direct { channels: 3 }).unwrap();
    let cam = Camera::from_matrices(vm, k, size, size).unwrap();
    let defaults = RasterOptions::default();
    let opts = RasterOptions {
        tile_size: std::env::var("TILE").map_or(defaults.tile_size, |t| t.parse().unwrap()),
        ..defaults
    };
    let run_forward = || raster::forward(scene.clone(), vec![cam], size, size, opts);
    let profiles = with_threads(Some(threads), || {
        // One untimed call first: the first calls of a process pay for page faults and the
        // allocator's growth, which would bias short runs.
        run_forward()?;
        let mut profiles = Vec::with_capacity(reps);
        for _ in 0..reps {
            let (t, cpu) = (Instant::now(), cpu_seconds());
            let (out, _) = run_forward()?;
            let wall = t.elapsed().as_secs_f64();
            profiles.push((wall, out.profile, cpu_seconds() - cpu));
        }
        Ok(profiles)
    })
    .unwrap();
    let ms = |s: f64| s * 1e3;
    let print = |name: &str, times: Vec<f64>| {
        let (lo, med) = min_median(times);
        println!("{name} ms: min {:.2} median {:.2}", ms(lo), ms(med));
    };
    println!("{n} Gaussians @ {size}^2, {threads} thread(s), {reps} calls");
    print("forward", profiles.iter().map(|p| p.0).collect());
    print("forward cpu", profiles.iter().map(|p| p.2).collect());
    type Stage = (&'static str, fn(&Profile) -> f64);
    let stages: [Stage; 4] = [
        ("project", |p| p.project),
        ("sort", |p| p.sort),
        ("bin", |p| p.bin),
        ("blend", |p| p.blend),
    ];
    for (name, stage) in stages {
        print(
            &format!("  {name}"),
            profiles.iter().map(|p| stage(&p.1)).collect(),
        );
    }
    let (out, state) = run_forward().unwrap();
    if std::env::var_os("BACKWARD").is_some() {
        let pixels = (size * size) as usize;
        let v_render: Vec<f32> = (0..pixels * 3)
            .map(|i| ((i % 7) as f32 - 3.0) * 1e-3)
            .collect();
        let v_alpha: Vec<f32> = (0..pixels).map(|i| ((i % 5) as f32 - 2.0) * 1e-3).collect();
        let (times, cpus) = with_threads(Some(threads), || {
            let (mut times, mut cpus) = (Vec::with_capacity(reps), Vec::with_capacity(reps));
            for _ in 0..reps {
                let (t, cpu) = (Instant::now(), cpu_seconds());
                let grads = raster::backward(
                    &state,
                    &v_render,
                    Some(&v_alpha),
                    raster::GradRequest {
                        means: true,
                        quats: true,
                        scales: true,
                        opacities: true,
                        colors: true,
                    },
                )?;
                times.push(t.elapsed().as_secs_f64());
                cpus.push(cpu_seconds() - cpu);
                if times.len() == 1 && std::env::var_os("HASH").is_some() {
                    let all = [&grads.means, &grads.quats, &grads.scales, &grads.opacities];
                    let flat = all.into_iter().flatten().flatten().chain(&grads.means2d);
                    println!("gradients hash {:016x}", bits_hash(flat));
                }
            }
            Ok((times, cpus))
        })
        .unwrap();
        print("backward", times);
        print("backward cpu", cpus);
    }
    println!(
        "intersections {}",
        state.per_camera[0].bins.n_intersections()
    );
    if std::env::var_os("HASH").is_some() {
        println!(
            "image hash {:016x}",
            bits_hash(out.render.iter().chain(&out.alpha))
        );
    }
    if std::env::var_os("EVALS").is_some() {
        let e = raster::count_evaluations(&state).expect("the counting replay fits in memory");
        println!(
            "forward evaluations {} blended {}",
            e.forward_evaluated, e.forward_blended
        );
        println!(
            "backward evaluations {} blended {}",
            e.backward_evaluated, e.backward_blended
        );
    }
}
