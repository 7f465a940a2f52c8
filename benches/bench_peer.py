"""OpenSplat's CPU rasterizer beside plantdreamer's, in one process, on one scene.

OpenSplat (https://github.com/pierotofy/OpenSplat) is AGPL-3.0: none of its code is in this
repository. This script compiles the user's own checkout of it as a torch C++ extension
(its `rasterizer/gsplat-cpu/gsplat_cpu.cpp`, plus the small binding in `peer_glue.cpp`
here that only exposes its functions to Python), then times both rasterizers on the
benchmark plant, interleaved, and compares their images and gradients.

    git clone https://github.com/pierotofy/OpenSplat /tmp/opensplat
    python benches/bench_peer.py --opensplat /tmp/opensplat

Without a checkout (no `--opensplat` and no `OPENSPLAT_DIR`) it prints how to get one and
leaves benches/results/peer.md as it is. Needs a C++ compiler and `ninja` (bench extra).

The peer is run as OpenSplat's trainer runs it on the CPU (`model.cpp`): projection by
torch tensor operations (differentiated by torch autograd), blending by its C++ loop over
Gaussians in depth order, its backward over per-pixel lists. Both get the same Gaussians,
camera, colours (no SH) and background. OpenSplat's projection puts the principal point
at the image centre and samples pixels at integer coordinates, which is gsplat's
convention with cx = W / 2 and pixel centres at +0.5: the camera below has exactly that.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from pathlib import Path

import torch

BENCHES = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCHES))

from raster_scene import orbit_cameras, synthetic_plant  # noqa: E402

from plantdreamer import _core, rasterization  # noqa: E402

RESULTS = BENCHES / "results"
GLUE = BENCHES / "peer_glue.cpp"
COMMAND = "python benches/bench_peer.py --opensplat DIR"
BACKGROUND = (0.75, 0.75, 0.75)


def build_peer(checkout: Path):
    """Compiles the peer from `checkout` (cached by torch under ~/.cache/torch_extensions)."""
    from torch.utils.cpp_extension import load

    # torch finds ninja on PATH only; the bench extra installs it beside this interpreter.
    os.environ["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    cpu_dir = checkout / "rasterizer" / "gsplat-cpu"
    source = cpu_dir / "gsplat_cpu.cpp"
    if not source.is_file():
        raise SystemExit(f"error: {source} not found: is {checkout} an OpenSplat checkout?")
    return load(
        name="opensplat_cpu_peer",
        sources=[str(GLUE), str(source)],
        extra_include_paths=[str(cpu_dir)],
        extra_cflags=["-O3", "-march=native"],
        verbose=False,
    )


def opengl_projection(fov_x: float, fov_y: float, near=0.001, far=1000.0) -> torch.Tensor:
    """OpenSplat's projection matrix (`model.cpp`), with the near/far planes it uses."""
    t, r = near * math.tan(0.5 * fov_y), near * math.tan(0.5 * fov_x)
    return torch.tensor(
        [
            [near / r, 0, 0, 0],
            [0, near / t, 0, 0],
            [0, 0, (far + near) / (far - near), -far * near / (far - near)],
            [0, 0, 1, 0],
        ],
        dtype=torch.float32,
    )


class PeerRasterize(torch.autograd.Function):
    """The peer's blending as OpenSplat's `RasterizeGaussiansCPU` wires it."""

    @staticmethod
    def forward(ctx, peer, width, height, xys, conics, colors, opacities, background, cov2d, depth):
        image, final_t, lists = peer.rasterize_forward(
            width, height, xys, conics, colors, opacities, background, cov2d, depth
        )
        ctx.peer, ctx.lists, ctx.size = peer, lists, (height, width)
        ctx.save_for_backward(xys, conics, colors, opacities, background, cov2d, depth, final_t)
        return image

    @staticmethod
    def backward(ctx, v_image):
        xys, conics, colors, opacities, background, cov2d, depth, final_t = ctx.saved_tensors
        v_alpha = torch.zeros_like(v_image[..., 0])
        v_xy, v_conic, v_colors, v_opacity = ctx.peer.rasterize_backward(
            *ctx.size, xys, conics, colors, opacities, background, cov2d, depth, final_t,
            ctx.lists, v_image.contiguous(), v_alpha,
        )  # fmt: skip
        return (
            None,
            None,
            None,
            v_xy,
            v_conic,
            v_colors,
            v_opacity.view_as(opacities),
            None,
            None,
            None,
        )


def peer_render(peer, params, viewmat, k, size):
    means, quats, scales, opacities, colors = params
    fx, fy = float(k[0, 0]), float(k[1, 1])
    fov_x, fov_y = 2 * math.atan(size / (2 * fx)), 2 * math.atan(size / (2 * fy))
    projmat = opengl_projection(fov_x, fov_y) @ viewmat
    xys, _radii, conics, cov2d, depth = peer.project(
        means, scales, quats / quats.norm(dim=-1, keepdim=True), viewmat, projmat,
        fx, fy, float(k[0, 2]), float(k[1, 2]), size, size,
    )  # fmt: skip
    background = torch.tensor(BACKGROUND)
    return PeerRasterize.apply(
        peer, size, size, xys, conics, colors, opacities, background, cov2d, depth
    )


def ours_render(params, viewmat, k, size, threads):
    image, _alpha, _meta = rasterization(
        *params, viewmat[None], k[None], size, size,
        backgrounds=torch.tensor([BACKGROUND]), threads=threads,
    )  # fmt: skip
    return image[0]


def step(render, params, target):
    """Forward and backward seconds of one L2 training step, the image and the gradients."""
    for p in params:
        p.grad = None
    t0 = time.perf_counter()
    image = render(params)
    t1 = time.perf_counter()
    (image - target).square().sum().backward()
    t2 = time.perf_counter()
    return t1 - t0, t2 - t1, image.detach(), [p.grad.clone() for p in params]


def relative_error(a: torch.Tensor, b: torch.Tensor) -> float:
    """max |a - b| / max |b|."""
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-30))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--opensplat", type=Path, default=os.environ.get("OPENSPLAT_DIR"))
    parser.add_argument("--gaussians", type=int, default=100_000)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--calls", type=int, default=3, help="calls per round and rasterizer")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    if args.opensplat is None:
        print(
            "bench_peer: skipped (no OpenSplat checkout). To run it:\n"
            "  git clone https://github.com/pierotofy/OpenSplat /tmp/opensplat\n"
            f"  {COMMAND.replace('DIR', '/tmp/opensplat')}"
        )
        return 0
    peer = build_peer(args.opensplat.resolve())
    torch.set_num_threads(args.threads)

    scene = synthetic_plant(args.gaussians)
    viewmats, ks = orbit_cameras(args.size, args.size)
    viewmat, k = viewmats[0], ks[0]
    renders = {
        "plantdreamer": lambda p: ours_render(p, viewmat, k, args.size, args.threads),
        "OpenSplat CPU": lambda p: peer_render(peer, p, viewmat, k, args.size),
    }
    params = [x.clone().requires_grad_(True) for x in scene]
    target = torch.full((args.size, args.size, 3), 0.5)
    times: dict[str, dict[str, list[float]]] = {n: {"fwd": [], "bwd": []} for n in renders}
    results = {}
    for name, render in renders.items():  # warm-up, and the outputs to compare
        results[name] = step(render, params, target)[2:]
    for _ in range(args.rounds):
        for name, render in renders.items():
            for _ in range(args.calls):
                fwd, bwd, _image, _grads = step(render, params, target)
                times[name]["fwd"].append(fwd)
                times[name]["bwd"].append(bwd)

    ours_image, ours_grads = results["plantdreamer"]
    peer_image, peer_grads = results["OpenSplat CPU"]
    image_diff = float((ours_image - peer_image).abs().max())
    names = ["means", "quats", "scales", "opacities", "colors"]
    grad_rows = [
        f"| {n} | {relative_error(pg, og):.2e} |"
        for n, og, pg in zip(names, ours_grads, peer_grads, strict=True)
    ]

    def ms(xs: list[float]) -> str:
        return f"{min(xs) * 1e3:.1f} ({statistics.median(xs) * 1e3:.1f})"

    rows = []
    for name in renders:
        f, b = times[name]["fwd"], times[name]["bwd"]
        both = [x + y for x, y in zip(f, b, strict=True)]
        rows.append(f"| {name} | {ms(f)} | {ms(b)} | {ms(both)} |")
    ratio = {
        key: min(times["OpenSplat CPU"][key]) / min(times["plantdreamer"][key])
        for key in ("fwd", "bwd")
    }
    calls = args.rounds * args.calls
    section = f"""## Peer: OpenSplat's CPU rasterizer (`benches/bench_peer.py`)

Command: `{COMMAND}` (an OpenSplat checkout, compiled here as a torch extension with
`-O3 -march=native`; its code is not part of plantdreamer). Scene: the benchmark plant,
{args.gaussians:,} Gaussians at {args.size}^2, one training step (render, L2 loss,
backward to means, quats, scales, opacities and colours), {args.threads} threads for
plantdreamer and for torch (OpenSplat blends on one thread; its projection runs on torch's
threads). {calls} steps per rasterizer in {args.rounds} interleaved rounds; min (median) ms.
plantdreamer blending kernel: `{_core.info()["blend_kernel"]}`.

| rasterizer | forward | backward | forward + backward |
|---|---|---|---|
{chr(10).join(rows)}

OpenSplat / plantdreamer, best calls: forward {ratio["fwd"]:.1f}x, backward {ratio["bwd"]:.1f}x.
Largest per-pixel difference between the two images: {image_diff:.3f} (the images differ
where OpenSplat's per-pixel lists and 3-sigma footprints depart from gsplat's semantics).
OpenSplat's gradients against plantdreamer's, as max |difference| / max |plantdreamer's|;
plantdreamer's match float64 references and finite differences in the test suite, so these
are OpenSplat's errors, including those that come from its different image:

| parameter | relative difference |
|---|---|
{chr(10).join(grad_rows)}
"""
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "peer.md").write_text(section)
    print(section)
    return 0


if __name__ == "__main__":
    sys.exit(main())
