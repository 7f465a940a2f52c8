//! Times the forward rasterizer per stage on a scene dumped by
//! `python benches/raster_scene.py --dump FILE [--n N] [--size S]`, without Python in the
//! way (for profiling with perf):
//!
//!     cargo run --release -p splat_core --example raster_timing -- FILE [THREADS] [REPS]
//!
//! `TILE=32` sets the tile size; `BACKWARD=1` also times the backward pass.
use std::time::Instant;

#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

use splat_core::raster::{self, Camera, ColorMode, RasterOptions, Scene};
use splat_core::threads::with_threads;

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
    let (best, profile) = with_threads(Some(threads), || {
        let mut best = (f64::INFINITY, Default::default());
        for _ in 0..reps {
            let t = Instant::now();
            let (out, _) = raster::forward(
                scene.clone(),
                vec![cam],
                size,
                size,
                RasterOptions {
                    tile_size: std::env::var("TILE").map_or(16, |t| t.parse().unwrap()),
                    ..Default::default()
                },
            )?;
            let dt = t.elapsed().as_secs_f64();
            if dt < best.0 {
                best = (dt, out.profile);
            }
        }
        Ok(best)
    })
    .unwrap();
    let ms = |s: f64| s * 1e3;
    if std::env::var_os("BACKWARD").is_some() {
        let (_, state) = raster::forward(
            scene.clone(),
            vec![cam],
            size,
            size,
            RasterOptions::default(),
        )
        .unwrap();
        let pixels = (size * size) as usize;
        let v_render: Vec<f32> = (0..pixels * 3)
            .map(|i| ((i % 7) as f32 - 3.0) * 1e-3)
            .collect();
        let v_alpha: Vec<f32> = (0..pixels).map(|i| ((i % 5) as f32 - 2.0) * 1e-3).collect();
        let best = with_threads(Some(threads), || {
            let mut best = f64::INFINITY;
            for _ in 0..reps {
                let t = Instant::now();
                raster::backward(
                    &state,
                    &v_render,
                    &v_alpha,
                    raster::GradRequest {
                        means: true,
                        quats: true,
                        scales: true,
                        opacities: true,
                        colors: true,
                    },
                )?;
                best = best.min(t.elapsed().as_secs_f64());
            }
            Ok(best)
        })
        .unwrap();
        println!("backward {:.1} ms", ms(best));
    }
    println!(
        "{n} @ {size}^2, {threads} thread(s): {:.1} ms (project {:.1}, sort {:.1}, bin {:.1}, blend {:.1})",
        ms(best),
        ms(profile.project),
        ms(profile.sort),
        ms(profile.bin),
        ms(profile.blend)
    );
}
