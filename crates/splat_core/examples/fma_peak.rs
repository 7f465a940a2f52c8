//! The roofline's ceiling: this CPU's measured peak vector arithmetic, from tight loops of
//! independent fused multiply-adds (AVX2, and AVX-512 where the CPU has it), and of
//! separate multiplies and adds (the blending kernels' mix: they use no FMA so that every
//! path gives the same bits).
//!
//!     cargo run --release -p splat_core --example fma_peak -- [THREADS] [SECONDS]
//!
//! Prints, per loop, the best of several timed runs on 1 and on THREADS threads, in
//! vector instructions per second and in f32 lane operations per second (an FMA counts as
//! one operation; FLOP/s are twice that).
#![allow(unsafe_code)]

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;
use std::time::Instant;

/// Independent accumulator chains: more than latency x pipes (4 x 2 on current cores).
const CHAINS: usize = 12;
const ITERS: u64 = 2_000_000;

/// Vector instructions of one `fma_avx2` call.
const FMA_OPS: u64 = ITERS * CHAINS as u64;

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn fma_avx2(seed: f32) -> f32 {
    let mut acc = [_mm256_set1_ps(seed); CHAINS];
    let (m, c) = (_mm256_set1_ps(0.999_99), _mm256_set1_ps(1e-6));
    for _ in 0..ITERS {
        for a in acc.iter_mut() {
            *a = _mm256_fmadd_ps(*a, m, c);
        }
    }
    fold(acc)
}

/// Half multiplies, half adds, in separate instructions: `FMA_OPS` instructions too.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn mul_add_avx2(seed: f32) -> f32 {
    let mut acc = [_mm256_set1_ps(seed); CHAINS];
    let (m, c) = (_mm256_set1_ps(0.999_99), _mm256_set1_ps(1e-6));
    for _ in 0..ITERS {
        for (i, a) in acc.iter_mut().enumerate() {
            *a = if i % 2 == 0 {
                _mm256_mul_ps(*a, m)
            } else {
                _mm256_add_ps(*a, c)
            };
        }
    }
    fold(acc)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn fma_avx512(seed: f32) -> f32 {
    let mut acc = [_mm512_set1_ps(seed); CHAINS];
    let (m, c) = (_mm512_set1_ps(0.999_99), _mm512_set1_ps(1e-6));
    for _ in 0..ITERS {
        for a in acc.iter_mut() {
            *a = _mm512_fmadd_ps(*a, m, c);
        }
    }
    acc.iter().map(|v| _mm512_reduce_add_ps(*v)).sum()
}

/// Keeps the results alive so the loops are not optimised away.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn fold(acc: [__m256; CHAINS]) -> f32 {
    let mut out = [0.0f32; 8];
    let mut sum = _mm256_setzero_ps();
    for a in acc {
        sum = _mm256_add_ps(sum, a);
    }
    // SAFETY: `out` holds 8 floats; storeu has no alignment requirement.
    unsafe { _mm256_storeu_ps(out.as_mut_ptr(), sum) };
    out.iter().sum()
}

/// Best instructions per second over `secs` seconds of `threads` threads each calling `f`.
fn peak(threads: usize, secs: f64, f: fn(f32) -> f32) -> f64 {
    let start = Instant::now();
    let mut best = 0.0f64;
    while start.elapsed().as_secs_f64() < secs {
        let t = Instant::now();
        let sinks: Vec<f32> = std::thread::scope(|s| {
            let hs: Vec<_> = (0..threads)
                .map(|i| s.spawn(move || f(1.0 + i as f32)))
                .collect();
            hs.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let dt = t.elapsed().as_secs_f64();
        std::hint::black_box(sinks);
        best = best.max((threads as u64 * FMA_OPS) as f64 / dt);
    }
    best
}

fn main() {
    let mut args = std::env::args().skip(1);
    let threads: usize = args.next().map_or(2, |a| a.parse().unwrap());
    let secs: f64 = args.next().map_or(2.0, |a| a.parse().unwrap());
    #[cfg(target_arch = "x86_64")]
    {
        type Loop = (&'static str, &'static str, usize, fn(f32) -> f32);
        let mut loops: Vec<Loop> = Vec::new();
        if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            // SAFETY: each closure calls a `target_feature` function only on a CPU that has
            // the feature (checked just above).
            loops.push(("fma", "avx2", 8, |x| unsafe { fma_avx2(x) }));
            loops.push(("mul+add", "avx2", 8, |x| unsafe { mul_add_avx2(x) }));
        }
        if is_x86_feature_detected!("avx512f") {
            // SAFETY: as above, AVX-512F detected.
            loops.push(("fma", "avx512", 16, |x| unsafe { fma_avx512(x) }));
        } else {
            println!("avx512: absent on this CPU");
        }
        for (name, isa, lanes, f) in loops {
            for t in [1, threads] {
                let ips = peak(t, secs, f);
                println!(
                    "{name} {isa} threads {t}: {:.2} G instr/s, {:.2} G lane-ops/s",
                    ips / 1e9,
                    ips * lanes as f64 / 1e9
                );
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    println!("no x86-64 vector loops on this CPU");
}
