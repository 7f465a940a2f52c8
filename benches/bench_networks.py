"""The SDS networks alone on CUDA: time and run-to-run bit-identity under each setting.

    python benches/bench_networks.py                 # full size, fp16 UNet/ControlNet, fp32 VAE

For ControlNet + UNet (batch 2: conditional and unconditional, as SDS runs them) and for the
VAE encoder's forward and backward at the SDS resolution, it times (CUDA events, median and
min of ``--reps`` after warm-up) and checks whether two calls on the same inputs give the same
bits, with PyTorch's default settings and with ``make_cuda_deterministic``'s, and the VAE with
its attention on the default and on the math kernel. Then the ten costliest CUDA kernels of
one ControlNet + UNet call under the deterministic settings (torch.profiler).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections.abc import Callable

import torch


def time_ms(fn: Callable[[], object], reps: int) -> tuple[float, float]:
    for _ in range(3):
        fn()
    times = []
    for _ in range(reps):
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        start.record()
        fn()
        end.record()
        torch.cuda.synchronize()
        times.append(start.elapsed_time(end))
    return statistics.median(times), min(times)


def set_deterministic(on: bool) -> None:
    torch.backends.cudnn.deterministic = on
    torch.use_deterministic_algorithms(on, warn_only=True)


def main(argv: list[str] | None = None) -> int:
    from plantdreamer.guidance.cuda_graph import GraphedAutogradCall, GraphedCall
    from plantdreamer.guidance.full_size import full_size_models
    from plantdreamer.guidance.models import deterministic_attention, make_cuda_deterministic

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sds", type=int, default=512)
    p.add_argument("--reps", type=int, default=20)
    args = p.parse_args(argv)
    if not torch.cuda.is_available():  # `make bench` on a machine without a GPU
        print("bench_networks: no CUDA GPU on this machine; nothing measured")
        return 0
    device = torch.device("cuda")
    make_cuda_deterministic()  # sets the cuBLAS workspace before the first call
    parts = full_size_models(device=device)
    unet, control = parts.unet.half(), parts.controlnet.half()
    vae = parts.vae.float()
    for m in (unet, control, vae):
        m.requires_grad_(False)
    g = torch.Generator(device).manual_seed(0)
    side = args.sds // 8
    x = torch.randn(2, 4, side, side, device=device, generator=g).half()
    t = torch.tensor([500, 500], device=device)
    emb = torch.randn(2, 77, 1024, device=device, generator=g).half()
    cond = torch.rand(2, 3, args.sds, args.sds, device=device, generator=g).half()
    rgb = torch.rand(1, 3, args.sds, args.sds, device=device, generator=g)

    @torch.no_grad()
    def unet_call() -> torch.Tensor:  # fresh inputs would not change the kernels run
        down, mid = control(
            x, t, encoder_hidden_states=emb, controlnet_cond=cond, return_dict=False
        )
        return unet(
            x,
            t,
            encoder_hidden_states=emb,
            down_block_additional_residuals=down,
            mid_block_additional_residual=mid,
        ).sample

    def vae_call(math: bool) -> torch.Tensor:
        image = rgb.clone().requires_grad_(True)
        context = deterministic_attention(device) if math else torch.enable_grad()
        with context:
            latents = vae.encode(image * 2 - 1).latent_dist.mean
        latents.backward(torch.ones_like(latents))
        return image.grad

    rows = []

    def row(name: str, settings: str, fn: Callable[[], torch.Tensor], twice: bool = True) -> None:
        med, best = time_ms(fn, args.reps)
        same = torch.equal(fn(), fn()) if twice else "-"
        rows.append(f"| {name} | {settings} | {med:.1f} / {best:.1f} | {same} |")

    unet_name = "ControlNet+UNet fp16, batch 2"
    vae_name = "VAE encode + backward fp32"
    for deterministic in (False, True):
        set_deterministic(deterministic)
        label = "deterministic" if deterministic else "default"
        row(unet_name, f"{label}, eager", unet_call)
        for math in (False, True):
            kernel = "math attention" if math else "default attention"
            row(vae_name, f"{label}, {kernel}", lambda m=math: vae_call(m))

    set_deterministic(True)
    graphed = GraphedCall(lambda _x: unet_call())
    row(unet_name, "deterministic, CUDA graph", lambda: graphed(x))
    eager_out = unet_call()
    rows.append(f"| graph replay == eager call | | | {torch.equal(graphed(x), eager_out)} |")
    unet.to(memory_format=torch.channels_last)
    control.to(memory_format=torch.channels_last)
    graphed_cl = GraphedCall(lambda _x: unet_call())
    row(unet_name, "deterministic, CUDA graph, channels_last", lambda: graphed_cl(x))
    row(unet_name, "deterministic, eager, channels_last", unet_call)
    rows.append(f"| channels_last == NCHW (graph) | | | {torch.equal(graphed_cl(x), eager_out)} |")
    graphed_vae = GraphedAutogradCall(lambda image: vae.encode(image).latent_dist.parameters)

    def vae_graph_call() -> torch.Tensor:
        image = rgb.clone().requires_grad_(True)
        with deterministic_attention(device):
            moments = graphed_vae(image * 2 - 1)
        moments.backward(torch.ones_like(moments))
        return image.grad

    row(vae_name, "deterministic, math attention, CUDA graphs", vae_graph_call)
    print(f"{torch.cuda.get_device_name(device)}, SDS {args.sds}, torch {torch.__version__}\n")
    print("| network | settings | ms median / min | same bits twice |")
    print("|---|---|---|---|")
    print("\n".join(rows))

    from torch.profiler import ProfilerActivity, profile

    for name, fn in ((unet_name, unet_call), (vae_name, lambda: vae_call(True))):
        with profile(activities=[ProfilerActivity.CUDA]) as prof:
            fn()
            torch.cuda.synchronize()
        events = prof.key_averages()
        gpu_us = sum(getattr(e, "self_device_time_total", 0) for e in events)
        print(f"\n{name}: GPU kernel time {gpu_us / 1000:.1f} ms per call (channels_last UNet)")
        print(prof.key_averages().table(sort_by="self_device_time_total", row_limit=6,
                                        max_name_column_width=60))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
