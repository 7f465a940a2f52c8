"""The VAE encoder's forward and backward, as SDS runs it, in each precision: time, the
render gradient's error against float32, and whether two calls give the same bits.

    python benches/bench_vae_precision.py                # CUDA: full size, batch 8 at 512
    python benches/bench_vae_precision.py --tiny         # the CPU: tiny VAE (a dry run)

The batch is the real half-batch of a B = 16 group with overlap (8 renders); the render
gradient is the input's gradient under a fixed random cotangent on the posterior's
parameters (what SDS's latent gradient becomes), as ``StableDiffusionDepthGuidance.encode``
computes it. Every setting is compared with the reference, float32 in NCHW with the
math attention kernel (the guidance's float32 path): relative error ||g - g_ref|| / ||g_ref||
and cosine. Settings: the VAE's dtype (float32, bfloat16, float16), its memory format (NCHW,
channels_last) and the attention kernel (``math``, the deterministic one the guidance
forces, or torch's default choice). Time: CUDA events (wall time on the CPU), median / min
of ``--reps`` after warm-up. ``--out`` writes the table and the JSON beside it. The
known answer judges a precision on the whole job (``scripts/known_answer.py --device cuda
--vae-dtype bfloat16``); this bench gives the per-call cost and error.
"""

from __future__ import annotations

import argparse
import copy
import itertools
import json
import statistics
import sys
import time
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host import host_line

RESULTS = Path(__file__).resolve().parent / "results"
DTYPES = ("float32", "bfloat16", "float16")
FORMATS = ("nchw", "channels_last")
ATTENTION = ("math", "default")


def timed_ms(fn: Callable[[], object], reps: int, cuda: bool) -> tuple[float, float]:
    for _ in range(2):
        fn()
    times = []
    for _ in range(reps):
        if cuda:
            start = torch.cuda.Event(enable_timing=True)
            end = torch.cuda.Event(enable_timing=True)
            start.record()
            fn()
            end.record()
            torch.cuda.synchronize()
            times.append(start.elapsed_time(end))
        else:
            t0 = time.perf_counter()
            fn()
            times.append(1000 * (time.perf_counter() - t0))
    return statistics.median(times), min(times)


def render_gradient(vae: Any, rgb: torch.Tensor, cotangent: torch.Tensor, dtype: torch.dtype,
                    attention: str) -> torch.Tensor:  # fmt: skip
    """d<cotangent, moments(rgb)>/d rgb, in float32, as the guidance's encode computes it."""
    from plantdreamer.guidance.models import deterministic_attention

    image = rgb.clone().requires_grad_(True)
    context = deterministic_attention(rgb.device) if attention == "math" else nullcontext()
    with context:
        moments = vae.encode((image * 2.0 - 1.0).to(dtype)).latent_dist.parameters
    moments.float().backward(cotangent)
    assert image.grad is not None
    return image.grad


def compare(g: torch.Tensor, ref: torch.Tensor) -> dict[str, float]:
    g, ref = g.double().reshape(-1), ref.double().reshape(-1)
    finite = bool(torch.isfinite(g).all())
    return {
        "finite": finite,
        "relative_error": float((g - ref).norm() / ref.norm()) if finite else float("nan"),
        "cosine": float(torch.nn.functional.cosine_similarity(g, ref, dim=0)),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--sds", type=int, help="image side (512; --tiny: 64)")
    p.add_argument("--reps", type=int, default=10)
    p.add_argument("--tiny", action="store_true", help="the tiny VAE on the CPU")
    p.add_argument("--out", type=Path, default=RESULTS / "vae_precision.md")
    args = p.parse_args(argv)
    cuda = torch.cuda.is_available() and not args.tiny
    if not cuda and not args.tiny:
        print("bench_vae_precision: no CUDA GPU on this machine; run with --tiny for a dry run")
        return 0
    device = torch.device("cuda" if cuda else "cpu")
    side = args.sds or (64 if args.tiny else 512)
    if cuda:
        from plantdreamer.guidance.full_size import full_size_models
        from plantdreamer.guidance.models import make_cuda_deterministic

        make_cuda_deterministic()
        vae = full_size_models(device=device).vae
    else:
        from plantdreamer.guidance.tiny import tiny_models

        vae = tiny_models().vae
    vae.requires_grad_(False).eval()
    g = torch.Generator(device).manual_seed(0)
    rgb = torch.rand(args.batch, 3, side, side, device=device, generator=g)
    with torch.no_grad():
        shape = vae.float().encode(rgb[:1] * 2 - 1).latent_dist.parameters.shape[1:]
    cotangent = torch.randn(args.batch, *shape, device=device, generator=g)

    master = vae.float()

    def configure(dtype: str, fmt: str) -> Any:
        """A copy of the float32 VAE in ``dtype`` and ``fmt`` (never cast from another
        low precision: bfloat16 weights cast to float16 would carry bfloat16's rounding)."""
        memory = torch.channels_last if fmt == "channels_last" else torch.contiguous_format
        return copy.deepcopy(master).to(dtype=getattr(torch, dtype), memory_format=memory)

    reference = render_gradient(master, rgb, cotangent, torch.float32, "math")
    rows = []
    for dtype, fmt, attention in itertools.product(DTYPES, FORMATS, ATTENTION):
        model = configure(dtype, fmt)
        torch_dtype = getattr(torch, dtype)

        def call(dt: torch.dtype = torch_dtype, at: str = attention, m: Any = model) -> Any:
            return render_gradient(m, rgb, cotangent, dt, at)

        try:
            first, second = call(), call()
            med, best = timed_ms(call, args.reps, cuda)
        except RuntimeError as exc:  # a kernel this device or dtype lacks
            rows.append({"dtype": dtype, "format": fmt, "attention": attention,
                         "error": str(exc).splitlines()[0]})  # fmt: skip
            continue
        rows.append({
            "dtype": dtype, "format": fmt, "attention": attention,
            "ms_median": med, "ms_min": best, "same_bits_twice": torch.equal(first, second),
            **compare(first, reference),
        })  # fmt: skip
        print(json.dumps(rows[-1]), flush=True)
    name = torch.cuda.get_device_name(device) if cuda else "cpu"
    command = "python benches/bench_vae_precision.py " + " ".join(argv or sys.argv[1:])
    lines = [
        "## The VAE's encode and backward in each precision (`benches/bench_vae_precision.py`)",
        "",
        f"Command: `{command.strip()}`; device {name}, host {host_line()}, torch "
        f"{torch.__version__}; {'full-size SD 2.1 VAE, random weights' if cuda else 'tiny VAE'}"
        f", batch {args.batch} at {side} px. Time: median / min of {args.reps}. Error: the "
        "render gradient against float32, NCHW, math attention.",
        "",
        "| dtype | format | attention | ms median / min | relative error | cosine | "
        "same bits twice |",
        "|---|---|---|---:|---:|---:|---|",
    ]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['dtype']} | {r['format']} | {r['attention']} | "
                         f"not run: {r['error']} | | | |")  # fmt: skip
            continue
        lines.append(
            f"| {r['dtype']} | {r['format']} | {r['attention']} | {r['ms_median']:.1f} / "
            f"{r['ms_min']:.1f} | {r['relative_error']:.2e} | {r['cosine']:.6f} | "
            f"{r['same_bits_twice']} |"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps({"device": name, "rows": rows}, indent=2))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
