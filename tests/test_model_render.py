"""The training model's render: activations off torch's thread pool, the same bits for any
torch thread count, a group's renders (``render_many``, its per-plant work on a pool) the
bits of each model's own, and the ground truth drawn from the same activated Gaussians."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch

from plantdreamer.cameras import orbit
from plantdreamer.gaussians import activate_opacities, activate_scales
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.model.render import FrozenScene, render_many
from plantdreamer.pipeline.truth.ground_truth import Splats

# Not a multiple of torch's vector width: torch.sigmoid's bits at its chunk edges depend on
# how many threads split the array, which is what the render must not inherit.
N = 100_003


@pytest.fixture
def model(random_gaussians) -> GaussianModel:
    return GaussianModel(random_gaussians(N, degree=1, seed=3))


def render_and_grads(model: GaussianModel) -> list[np.ndarray]:
    for p in model.params.values():
        p.grad = None
    camera = orbit(4.0, 20.0, 30.0, 50.0, 48, 40)
    image, alpha, _ = model.render([camera], 0.5)
    weights = torch.linspace(-1.0, 1.0, image.numel()).reshape(image.shape)
    ((image * weights).sum() + alpha.sum()).backward()
    grads = [model.params[k].grad for k in ("log_scales", "opacity_logits", "means")]
    assert all(g is not None for g in grads)
    return [image.detach().numpy(), alpha.detach().numpy(), *(g.numpy() for g in grads)]


def test_render_and_gradients_are_the_same_bits_for_any_torch_thread_count(model):
    before = torch.get_num_threads()
    try:
        runs = []
        for threads in (1, 2, 4):
            torch.set_num_threads(threads)
            runs.append(render_and_grads(model))
    finally:
        torch.set_num_threads(before)
    for other in runs[1:]:
        for a, b in zip(runs[0], other, strict=True):
            assert a.tobytes() == b.tobytes()


def small_models(random_gaussians) -> list[GaussianModel]:
    return [GaussianModel(random_gaussians(3000 + 500 * k, degree=1, seed=k)) for k in range(3)]


def group_cameras() -> list:
    return [orbit(4.0, 20.0, 30.0 + 90.0 * k, 50.0, 48, 40) for k in range(3)]


def render_bits(image, alpha, model) -> list[bytes]:
    grads = [model.params[k].grad for k in ("means", "log_scales", "opacity_logits", "sh_dc")]
    return [t.detach().numpy().tobytes() for t in (image, alpha, *grads)]


def test_render_many_on_a_pool_gives_each_models_own_bits(random_gaussians):
    alone = []
    for model, camera in zip(small_models(random_gaussians), group_cameras(), strict=True):
        image, alpha, _ = model.render([camera], 0.5)
        torch.autograd.backward([image, alpha], [image.detach() - 0.5, alpha.detach()])
        alone.append(render_bits(image, alpha, model))
    models = small_models(random_gaussians)
    with ThreadPoolExecutor(3) as pool:
        rendered, cuts = render_many(
            models, group_cameras(), 0.5, lambda fn, ks: list(pool.map(fn, ks))
        )
        roots = [t for image, alpha, _ in rendered for t in (image, alpha)]
        grads = [g for image, alpha, _ in rendered for g in (image.detach() - 0.5, alpha.detach())]
        torch.autograd.backward(roots, grads)
        list(pool.map(lambda cut: cut.backward(), cuts))
    pooled = [render_bits(r[0], r[1], m) for r, m in zip(rendered, models, strict=True)]
    assert pooled == alone


def test_render_manys_pool_tasks_keep_the_callers_no_grad(random_gaussians):
    with ThreadPoolExecutor(2) as pool, torch.no_grad():
        rendered, _ = render_many(
            small_models(random_gaussians)[:2],
            group_cameras()[:2],
            0.5,
            lambda fn, ks: list(pool.map(fn, ks)),
        )
    assert not any(r[0].requires_grad or r[2]["means2d"].requires_grad for r in rendered)


def test_activation_gradients_follow_torchs_formulas(model):
    ls = model.params["log_scales"].detach().clone().requires_grad_(True)
    lo = model.params["opacity_logits"].detach().clone().requires_grad_(True)
    from plantdreamer.pipeline.model.gaussian_model import _Activations

    scales, opacities = _Activations.apply(ls, lo)
    s_ref = activate_scales(ls.detach().numpy())
    o_ref = activate_opacities(lo.detach().numpy())
    assert scales.detach().numpy().tobytes() == s_ref.tobytes()
    assert opacities.detach().numpy().tobytes() == o_ref.tobytes()
    # Within float32 rounding of torch's own exp and sigmoid.
    np.testing.assert_allclose(s_ref, torch.exp(ls).detach().numpy(), rtol=1e-6)
    np.testing.assert_allclose(o_ref, torch.sigmoid(lo).detach().numpy(), rtol=1e-6)
    rng = np.random.default_rng(0)
    vs = torch.from_numpy(rng.normal(size=s_ref.shape).astype(np.float32))
    vo = torch.from_numpy(rng.normal(size=o_ref.shape).astype(np.float32))
    torch.autograd.backward([scales, opacities], [vs, vo])
    s, o = torch.from_numpy(s_ref), torch.from_numpy(o_ref)
    assert torch.equal(ls.grad, vs * s)  # exp's backward
    assert torch.equal(lo.grad, vo * (1 - o) * o)  # sigmoid's backward, torch's order


def test_ground_truth_reads_the_renders_activated_gaussians(model):
    splats = Splats.of(model)
    p = model.params
    assert splats.scales.numpy().tobytes() == activate_scales(p["log_scales"].detach()).tobytes()
    assert (
        splats.opacities.numpy().tobytes()
        == activate_opacities(p["opacity_logits"].detach()).tobytes()
    )


@pytest.mark.parametrize("mode", ["ED", "RGB"])
def test_a_frozen_scene_renders_the_bits_of_its_model_from_every_camera(model, mode):
    frozen = FrozenScene(model, mode)
    for azimuth in (0.0, 130.0):
        camera = orbit(4.0, 20.0, azimuth, 50.0, 48, 40)
        with torch.no_grad():
            expected = model.render([camera], 0.5, mode)
        got = frozen.render([camera], 0.5)
        assert torch.equal(got[0], expected[0]) and torch.equal(got[1], expected[1])
    with torch.no_grad():  # activations made once: a later change of the logits is unseen
        model.params["opacity_logits"].add_(1.0)
    assert torch.equal(frozen.render([camera], 0.5)[0], got[0])


@pytest.mark.parametrize("mode", ["ED", "RGB"])
def test_renders_without_gradients_are_the_same_bits_for_every_tile_size(model, mode):
    """A depth map does not depend on the tile size (the bench compares their cost): a
    pixel's value depends only on the Gaussians that reach it, in depth order, not on the
    tiles that listed them (100k Gaussians, images not a multiple of any tile)."""
    from plantdreamer.pipeline.model.gaussian_model import camera_args
    from plantdreamer.rasterizer import RASTER_DEFAULTS, rasterization

    scene = FrozenScene(model, mode).scene
    for azimuth, distance in ((0.0, 4.0), (130.0, 2.5)):
        args = camera_args([orbit(distance, 20.0, azimuth, 50.0, 150, 110)], 0.5, mode)
        renders = []
        for tile in (RASTER_DEFAULTS["tile_size"], 8, 16, 24, 64):
            with torch.no_grad():
                image, alpha, meta = rasterization(**scene, **args, tile_size=tile)
            renders.append((image.numpy().tobytes(), alpha.numpy().tobytes()))
        assert int(meta["n_visible"][0]) > 1000 and float(alpha.max()) > 0.9  # a full image
        assert all(r == renders[0] for r in renders[1:])
