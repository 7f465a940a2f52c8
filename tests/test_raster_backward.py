"""Rasterizer gradients against torch autograd through the float64 reference, finite
differences and gradcheck; determinism and the requires_grad contract."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import raster_native as native
import raster_reference as ref
from plantdreamer import rasterization

W = H = 40
NAMES = ("means", "quats", "scales", "opacities", "colors")


def rel_err(got: torch.Tensor, want: torch.Tensor) -> float:
    return ((got.double() - want).norm() / want.norm().clamp_min(1e-30)).item()


def reference_loss(scene64, viewmats, ks, weights, *, sh_degree, mode, aa, bg, offsets):
    loss = 0.0
    for i in range(viewmats.shape[0]):
        feat, alpha = ref.render(
            *scene64,
            viewmats[i].double(),
            ks[i].double(),
            W,
            H,
            sh_degree=sh_degree,
            with_color=mode != "D",
            with_depth=mode != "RGB",
            antialiased=aa,
            means2d_offset=offsets[i],
        )
        alpha = alpha[..., None]
        if bg is not None:
            feat = torch.cat([feat[..., :3] + bg[i].double() * (1 - alpha), feat[..., 3:]], -1)
        if mode.endswith("ED"):
            feat = torch.cat([feat[..., :-1], feat[..., -1:] / alpha.clamp_min(1e-10)], -1)
        loss = loss + (feat * weights[0][i].double()).sum() + (alpha * weights[1][i].double()).sum()
    return loss


CASES = [
    # (sh_degree, render_mode, antialiased, background, cameras)
    (None, "RGB+D", False, True, 2),
    (3, "RGB", False, False, 1),
    (1, "RGB+ED", True, True, 1),
    (None, "D", False, False, 1),
    (2, "RGB+D", True, False, 2),
    (1, "RGB", True, True, 2),  # the background blended by the core
]


@pytest.mark.parametrize(("sh_degree", "mode", "aa", "use_bg", "n_cams"), CASES)
@pytest.mark.parametrize("seed", [0, 1])
def test_gradients_match_reference_autograd(sh_degree, mode, aa, use_bg, n_cams, seed):
    scene = ref.plant_scene(seed, n=120, sh_degree=sh_degree)
    viewmats, ks = ref.scene_cameras(W, H, n=n_cams)
    bg = torch.rand(n_cams, 3, generator=torch.Generator().manual_seed(seed)) if use_bg else None
    params = [x.clone().requires_grad_(True) for x in scene]
    colors, alphas, meta = rasterization(
        *params,
        viewmats,
        ks,
        W,
        H,
        sh_degree=sh_degree,
        backgrounds=bg,
        render_mode=mode,
        rasterize_mode="antialiased" if aa else "classic",
    )
    g = torch.Generator().manual_seed(100 + seed)
    weights = (torch.randn(colors.shape, generator=g), torch.randn(alphas.shape, generator=g))
    ((colors * weights[0]).sum() + (alphas * weights[1]).sum()).backward()

    scene64 = [x.double().requires_grad_(True) for x in scene]
    offsets = torch.zeros(n_cams, len(scene[0]), 2, dtype=torch.float64, requires_grad=True)
    loss = reference_loss(
        scene64,
        viewmats,
        ks,
        weights,
        sh_degree=sh_degree,
        mode=mode,
        aa=aa,
        bg=bg,
        offsets=offsets,
    )
    loss.backward()
    for name, p, q in zip(NAMES, params, scene64, strict=True):
        if mode == "D" and name == "colors":
            assert p.grad is None or p.grad.abs().max() == 0
            continue
        assert q.grad.norm() > 0, name
        assert rel_err(p.grad, q.grad) <= 1e-3, (name, rel_err(p.grad, q.grad))
    assert rel_err(meta["means2d"].grad, offsets.grad) <= 1e-3


def test_only_inputs_that_require_grad_get_gradients():
    scene = ref.plant_scene(3, n=60)
    viewmats, ks = ref.scene_cameras(W, H)
    means = scene[0].clone().requires_grad_(True)
    colors_in = scene[4].clone().requires_grad_(True)
    img, alpha, meta = rasterization(means, *scene[1:4], colors_in, viewmats, ks, W, H)
    (img.sum() + alpha.sum()).backward()
    assert means.grad is not None and colors_in.grad is not None
    assert all(x.grad is None for x in scene[1:4])
    assert meta["means2d"].grad is not None
    # The native call skips groups that are switched off.
    out = native.forward(*[x.numpy() for x in scene], viewmats.numpy(), ks.numpy(), W, H)
    grads = native.backward(
        out["state"],
        np.ones_like(out["render"]),
        np.ones_like(out["alpha"]),
        means=False,
        colors=False,
    )
    assert grads["means"] is None and grads["colors"] is None
    assert grads["quats"].shape == (60, 4) and grads["means2d"].shape == (1, 60, 2)


def test_no_grad_mode_builds_no_graph():
    scene = ref.plant_scene(3, n=20)
    viewmats, ks = ref.scene_cameras(W, H)
    means = scene[0].clone().requires_grad_(True)
    with torch.no_grad():
        img, _, meta = rasterization(means, *scene[1:], viewmats, ks, W, H)
    assert not img.requires_grad and not meta["means2d"].requires_grad


def test_native_gradients_match_finite_differences():
    # Four large splats near the image centre: every pixel is inside every alpha >= 1/255
    # contour, no pixel terminates early and no alpha reaches 0.99, so the image is smooth in
    # all parameters and central differences converge. The loss is summed in float64.
    g = torch.Generator().manual_seed(0)
    scene = [
        0.1 * torch.randn(4, 3, generator=g),
        torch.randn(4, 4, generator=g),
        0.6 + 0.3 * torch.rand(4, 3, generator=g),
        0.3 + 0.4 * torch.rand(4, generator=g),
        torch.rand(4, 3, generator=g),
    ]
    viewmats, ks = ref.scene_cameras(24, 24, distance=2.5)
    w_img = torch.randn(1, 24, 24, 3, generator=g, dtype=torch.float64)
    w_alpha = torch.randn(1, 24, 24, 1, generator=g, dtype=torch.float64)

    def loss(params):
        img, alpha, _ = rasterization(*params, viewmats, ks, 24, 24)
        return (img.double() * w_img).sum() + (alpha.double() * w_alpha).sum()

    params = [x.clone().requires_grad_(True) for x in scene]
    loss(params).backward()
    for i, name in enumerate(NAMES):
        direction = torch.randn(scene[i].shape, generator=g)
        direction /= direction.norm()
        analytic = (params[i].grad.double() * direction).sum().item()

        def quotient(h, i=i, direction=direction):
            with torch.no_grad():
                plus = [x.clone() for x in scene]
                minus = [x.clone() for x in scene]
                plus[i] += h * direction
                minus[i] -= h * direction
                return (loss(plus) - loss(minus)).item() / (2 * h)

        fd = quotient(1e-3)
        assert abs(analytic) > 1e-2, name  # the check must have something to check
        assert abs(fd - analytic) <= 2e-3 * max(1.0, abs(analytic)), (name, fd, analytic)


def test_reference_passes_gradcheck():
    scene = ref.plant_scene(5, n=4)
    scene[2] *= 4.0
    scene[3] = scene[3].clamp(0.2, 0.8)
    viewmats, ks = ref.scene_cameras(12, 12, distance=2.5)
    inputs = tuple(x.double().requires_grad_(True) for x in scene)

    def f(*params):
        feat, alpha = ref.render(
            *params, viewmats[0].double(), ks[0].double(), 12, 12, with_depth=True
        )
        return feat, alpha

    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_gradients_are_bit_identical_across_threads_runs_and_kernels():
    scene = ref.plant_scene(6, n=2000, sh_degree=3)
    viewmats, ks = ref.scene_cameras(64, 64, n=2)
    arrays = [x.numpy() for x in scene]
    results = []
    # Threads 1, 2, 2 again, then the scalar kernels instead of the SIMD ones (where the CPU
    # has them): all must give the same bits.
    for threads, simd in ((1, True), (2, True), (2, True), (2, False)):
        out = native.forward(
            *arrays,
            viewmats.numpy(),
            ks.numpy(),
            64,
            64,
            sh_degree=3,
            render_depth=True,
            simd=simd,
            threads=threads,
        )
        rng = np.random.default_rng(0)
        v_r = rng.standard_normal(out["render"].shape).astype(np.float32)
        v_a = rng.standard_normal(out["alpha"].shape).astype(np.float32)
        results.append(native.backward(out["state"], v_r, v_a, threads=threads))
    for key in ("means", "quats", "scales", "opacities", "colors", "means2d"):
        for other in results[1:]:
            assert np.array_equal(results[0][key], other[key]), key


def test_saved_state_is_linear_in_gaussians_pixels_and_intersections():
    scene = ref.plant_scene(7, n=3000)
    viewmats, ks = ref.scene_cameras(96, 80, n=2)
    out = native.forward(
        *[x.numpy() for x in scene], viewmats.numpy(), ks.numpy(), 96, 80, render_depth=True
    )
    n, c, ch = 3000, 2, 4
    isect = int(out["n_intersections"].sum())
    tile_pixels = c * 6 * 5 * 256  # ceil(96/16) x ceil(80/16) tiles of 256 pixels
    splat = 48  # bytes of one projected splat (12 f32)
    record = 64  # bytes of one blend record (splat and features in a cache line)
    # Inputs; per camera splats, features, order and blend records.
    per_gaussian = 4 * (3 + 4 + 3 + 1 + 3) + c * (splat + 4 * ch + 8 + record)
    per_isect = 4  # the tile lists (splats and features are gathered per tile when used)
    per_tile_pixel = 4 * ch + 4 + 4  # features, final T, last index
    size = per_gaussian * n + per_isect * isect + per_tile_pixel * tile_pixels
    assert out["state"].nbytes <= size + 4 * (31 + 1) * c
    assert out["state"].nbytes >= per_isect * isect + per_tile_pixel * tile_pixels


@pytest.mark.parametrize("channels", [1, 2, 5, 8])
def test_feature_channel_counts_match_reference(channels):
    # Colours of any width (the kernels special-case 1, 3 and 4 channels; the SIMD backward
    # keeps up to 4 in registers and hands wider features to the scalar kernel).
    scene = list(ref.plant_scene(3, n=150))
    g = torch.Generator().manual_seed(channels)
    scene[4] = torch.rand(len(scene[0]), channels, generator=g)
    viewmats, ks = ref.scene_cameras(W, H)
    params = [x.clone().requires_grad_(True) for x in scene]
    colors, alphas, _ = rasterization(*params, viewmats, ks, W, H)
    assert colors.shape == (1, H, W, channels)
    weights = (torch.randn(colors.shape, generator=g), torch.randn(alphas.shape, generator=g))
    ((colors * weights[0]).sum() + (alphas * weights[1]).sum()).backward()

    scene64 = [x.double().requires_grad_(True) for x in scene]
    feat, alpha = ref.render(*scene64, viewmats[0].double(), ks[0].double(), W, H)
    assert (colors[0].double() - feat).abs().max() <= 1e-4
    (
        (feat * weights[0][0].double()).sum() + (alpha * weights[1][0, ..., 0].double()).sum()
    ).backward()
    for name, p, q in zip(NAMES, params, scene64, strict=True):
        assert q.grad.norm() > 0, name
        assert rel_err(p.grad, q.grad) <= 1e-3, (name, rel_err(p.grad, q.grad))


@pytest.mark.parametrize("size", [(2, 48, 64), (1, 512, 512)])
@pytest.mark.parametrize("permuted_grad", [False, True])
@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("used", ["both", "render"])
def test_the_core_blends_the_background_with_the_bits_of_the_torch_expression(
    size, permuted_grad, channels, used
):
    """A background behind 1 or 3 colour channels is blended by the core: its render, alpha
    and every gradient must be the bits of the call without it followed by
    ``color + bg * (1 - alpha)`` through autograd, signed zeros included, whether the alpha
    gets a gradient of its own or not."""
    c, h, w = size
    g = torch.Generator().manual_seed(c * h + channels)
    scene = ref.plant_scene(c * h, n=150)
    scene[4] = scene[4][:, :channels].contiguous()
    viewmats, ks = ref.scene_cameras(w, h, n=c)
    bg = torch.rand(c, channels, generator=g)
    bg[-1, 0] = 0.0
    v = torch.randn(c, channels, h, w, generator=g).permute(0, 2, 3, 1)
    if not permuted_grad:
        v = v.contiguous()
    v[0, :4], v[0, 4] = 0.0, -0.0
    v_alpha = torch.randn(c, h, w, 1, generator=g)

    def run(in_core):
        params = [p.clone().requires_grad_() for p in scene]
        call = dict(zip(NAMES, params, strict=True))
        call |= {"viewmats": viewmats, "Ks": ks, "width": w, "height": h}
        if in_core:
            render, alpha, meta = rasterization(**call, backgrounds=bg)
        else:
            color, alpha, meta = rasterization(**call)
            render = color + bg[:, None, None, :] * (1.0 - alpha)
        roots, grads = ([render, alpha], [v, v_alpha]) if used == "both" else ([render], [v])
        torch.autograd.backward(roots, grads)
        tensors = [render, alpha, meta["means2d"].grad, *(p.grad for p in params)]
        return [t.detach().contiguous().view(torch.int32) for t in tensors]

    core, torch_expression = run(True), run(False)
    assert bool((core[1] != 0).any())  # something was rendered
    for got, want in zip(core, torch_expression, strict=True):
        assert torch.equal(got, want)
