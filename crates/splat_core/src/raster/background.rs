//! A background colour behind a camera's blended features: `render + bg (1 - alpha)` per
//! pixel, and the gradient it adds to the alpha, in the float32 operations and order of the
//! torch expression `render + bg[:, None, None, :] * (1 - alpha)` and its autograd (the
//! Python tests compare the bits, signed zeros included).
//!
//! In the core rather than in numpy or torch after the call: one parallel pass over the
//! image each way, where the numpy blend ran on one thread on the caller's critical path
//! (4.3 ms forward and 2.5 ms backward per 768 px render, BENCHMARKS.md).

use rayon::prelude::*;

use crate::memory::try_filled;
use crate::CoreResult;

/// Pixels per parallel task.
const CHUNK: usize = 16 * 1024;

/// `render[p][k] += (1 - alpha[p]) * bg[k]` for one camera's [P, ch] render, [P] alpha and
/// [ch] background: the torch order `render + (bg * (1 - alpha))`.
pub(super) fn blend(render: &mut [f32], alpha: &[f32], bg: &[f32]) {
    let ch = bg.len();
    render
        .par_chunks_mut(CHUNK * ch)
        .zip(alpha.par_chunks(CHUNK))
        .for_each(|(pixels, alphas)| {
            for (px, &a) in pixels.chunks_exact_mut(ch).zip(alphas) {
                let one_minus = 1.0 - a;
                for (v, &b) in px.iter_mut().zip(bg) {
                    *v += one_minus * b;
                }
            }
        });
}

/// The alpha gradient of one camera with the background blended: the caller's `v_alpha`
/// (None: the alpha itself got none) plus the blend's own, minus the channel sum of
/// `v_render * bg` in torch's order ((0 + v0 b0) + v1 b1) + v2 b2 (the leading + 0, which
/// turns a -0 into +0 as torch's sum of several channels does, only for more than one).
pub(super) fn alpha_gradient(
    v_render: &[f32],
    v_alpha: Option<&[f32]>,
    bg: &[f32],
) -> CoreResult<Vec<f32>> {
    let ch = bg.len();
    let pixels = v_render.len() / ch;
    let mut out = try_filled(pixels, 0.0f32)?;
    out.par_chunks_mut(CHUNK)
        .zip(v_render.par_chunks(CHUNK * ch))
        .enumerate()
        .for_each(|(i, (g, v))| {
            for (p, (g, px)) in g.iter_mut().zip(v.chunks_exact(ch)).enumerate() {
                let mut acc = px[0] * bg[0];
                if ch > 1 {
                    acc += 0.0;
                }
                for k in 1..ch {
                    acc += px[k] * bg[k];
                }
                let own = -acc;
                *g = match v_alpha {
                    Some(va) => va[i * CHUNK + p] + own,
                    None => own,
                };
            }
        });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_blend_is_render_plus_bg_times_one_minus_alpha() {
        let mut render = vec![0.25, 0.5, -0.0, 1.0, 0.0, 0.0];
        blend(&mut render, &[0.5, 1.0], &[0.2, 0.4, 0.0]);
        let want = [
            0.25 + 0.5 * 0.2,
            0.5 + 0.5 * 0.4,
            -0.0 + 0.5 * 0.0,
            1.0,
            0.0,
            0.0,
        ];
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&render), bits(&want));
    }

    #[test]
    fn the_alpha_gradient_sums_the_channels_in_torchs_order() {
        let bg = [0.5, 0.25, 2.0];
        let v = [1.0, 2.0, 3.0, 0.0, -0.0, 0.0];
        let g = alpha_gradient(&v, None, &bg).unwrap();
        assert_eq!(g[0], -(((1.0f32 * 0.5 + 0.0) + 2.0 * 0.25) + 3.0 * 2.0));
        // An all-zero pixel: -((0 + 0) ...) = -0 for three channels, as torch's sum gives.
        assert_eq!(g[1].to_bits(), (-0.0f32).to_bits());
        let with = alpha_gradient(&v, Some(&[1.0, 0.5]), &bg).unwrap();
        assert_eq!(with, vec![1.0 + g[0], 0.5 + g[1]]);
        // One channel: no + 0, so v = -0 gives -(-0 * b) = +0 and v = +0 gives -0.
        let one = alpha_gradient(&[-0.0, 0.0], None, &[0.5]).unwrap();
        assert_eq!(
            one.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            vec![0, (-0.0f32).to_bits()]
        );
    }

    #[test]
    fn chunks_cover_every_pixel() {
        let pixels = 2 * CHUNK + 7;
        let v: Vec<f32> = (0..pixels * 3).map(|i| (i % 11) as f32).collect();
        let va: Vec<f32> = (0..pixels).map(|i| (i % 5) as f32).collect();
        let bg = [0.5, 1.5, -1.0];
        let g = alpha_gradient(&v, Some(&va), &bg).unwrap();
        for p in [0, CHUNK - 1, CHUNK, 2 * CHUNK + 6] {
            let px = &v[3 * p..3 * p + 3];
            let own = -(((px[0] * bg[0] + 0.0) + px[1] * bg[1]) + px[2] * bg[2]);
            assert_eq!(g[p], va[p] + own, "pixel {p}");
        }
        let mut render = v.clone();
        let alpha: Vec<f32> = (0..pixels).map(|i| (i % 3) as f32 / 3.0).collect();
        blend(&mut render, &alpha, &bg);
        let last = 2 * CHUNK + 6;
        assert_eq!(
            render[3 * last + 2],
            v[3 * last + 2] + (1.0 - alpha[last]) * bg[2]
        );
    }
}
