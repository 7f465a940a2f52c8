"""Many scenes in one native call (``rasterization_many``, ``_core.rasterize_*_many``): the
bits of separate calls on any thread count, forward and gradients, with the scenes' Python
work on one thread or a pool's (``RasterBatch``'s stages); a bad scene fails alone; a group
trained with one call per step gives the bytes of one call per plant, and of its plants'
host work on one thread."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch

import raster_native as native
import raster_reference as ref
from plantdreamer import _core, rasterization
from plantdreamer.errors import InputError
from plantdreamer.rasterizer import RasterBatch, rasterization_many

W, H = 44, 36
NAMES = ("means", "quats", "scales", "opacities", "colors")
# (seed, Gaussians, sh_degree, render_mode, cameras, background)
SCENES = [
    (0, 150, 1, "RGB", 1, True),
    (1, 260, 1, "RGB", 1, True),
    (2, 90, 1, "RGB", 1, True),
    (3, 200, 1, "RGB", 1, True),
]


def scene_call(seed, n, sh_degree, mode, n_cams, use_bg):
    """rasterization's keyword arguments, with leaf parameters that need gradients."""
    params = [p.clone().requires_grad_(True) for p in ref.plant_scene(seed, n, sh_degree)]
    viewmats, ks = ref.scene_cameras(W, H, n=n_cams, distance=1.8 + 0.1 * seed)
    bg = torch.full((n_cams, 3), 0.25) if use_bg else None
    call = dict(zip(NAMES, params, strict=True))
    call |= {"viewmats": viewmats, "Ks": ks, "width": W, "height": H, "sh_degree": sh_degree,
             "backgrounds": bg, "render_mode": mode}  # fmt: skip
    return call, params


def upstream(render, alpha, seed):
    g = torch.Generator().manual_seed(100 + seed)
    return torch.rand(render.shape, generator=g) - 0.5, torch.rand(alpha.shape, generator=g)


def bits(t):
    return t.detach().contiguous().numpy().view(np.uint8).tobytes()


def fingerprint(render, alpha, meta, params):
    out = [bits(render), bits(alpha), bits(meta["means2d"].grad), bits(meta["radii"])]
    out += [bits(meta["depths"])] + [bits(p.grad) for p in params]
    return out


def roots_and_grads(render, alpha, seed, used):
    """The outputs that get a gradient and their upstream gradients: both, or only the
    render or the alpha (``used``)."""
    vr, va = upstream(render, alpha, seed)
    pairs = {"both": [(render, vr), (alpha, va)], "render": [(render, vr)],
             "alpha": [(alpha, va)]}[used]  # fmt: skip
    return [r for r, _ in pairs], [g for _, g in pairs]


def separate(threads, used="both"):
    prints = []
    for spec in SCENES:
        call, params = scene_call(*spec)
        render, alpha, meta = rasterization(**call, threads=threads)
        torch.autograd.backward(*roots_and_grads(render, alpha, spec[0], used))
        prints.append(fingerprint(render, alpha, meta, params))
    return prints


def staged_on(pool, calls, threads=None):
    """``rasterization_many`` as ``RasterBatch``'s stages, each scene's a task of ``pool``."""
    batch = RasterBatch(calls, threads=threads)
    list(pool.map(batch.prepare, range(len(batch))))
    batch.render()
    list(pool.map(batch.finish, range(len(batch))))
    return batch.results()


def together(threads, used="both", pool=None):
    made = [scene_call(*spec) for spec in SCENES]
    calls = [c for c, _ in made]
    if pool is None:
        results = rasterization_many(calls, threads=threads)
    else:
        results = staged_on(pool, calls, threads)
    roots, grads = [], []
    for spec, (render, alpha, _) in zip(SCENES, results, strict=True):
        r, g = roots_and_grads(render, alpha, spec[0], used)
        roots += r
        grads += g
    torch.autograd.backward(roots, grads)
    return [fingerprint(*r, p) for r, (_, p) in zip(results, made, strict=True)]


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_many_scenes_give_the_bits_of_separate_calls(threads):
    alone = separate(threads=1)
    assert all(any(b != 0 for b in f[0]) for f in alone)  # images that are not empty
    assert together(threads) == alone


def test_one_scene_is_the_many_scene_call_of_one():
    """``rasterization`` renders through the one autograd node of ``rasterization_many``."""
    call, _ = scene_call(*SCENES[0])
    _, alpha, _ = rasterization(**call)
    assert type(alpha.grad_fn).__name__ == "_RasterizeManyFunctionBackward"


@pytest.mark.parametrize("used", ["both", "render", "alpha"])
def test_the_scenes_python_work_on_a_pool_gives_the_same_bits(used):
    """The background blends run inside the many-scene node (on the pool, in ``finish``):
    its gradients must equal the separate calls' whichever outputs get one."""
    alone = separate(threads=1, used=used)
    with ThreadPoolExecutor(3) as pool:
        pooled = together(2, used=used, pool=pool)
    assert pooled == alone
    assert together(2, used=used) == alone


def test_a_batch_refuses_stages_out_of_order():
    calls = [scene_call(*spec)[0] for spec in SCENES[:2]]
    batch = RasterBatch(calls)
    batch.prepare(0)
    with pytest.raises(RuntimeError, match="prepared first"):
        batch.render()
    batch.prepare(1)
    batch.render()
    batch.finish(0)
    with pytest.raises(RuntimeError, match="scene 1 was not finished"):
        batch.results()


def test_a_bad_scene_fails_alone_and_is_named():
    made = [scene_call(*spec) for spec in SCENES[:3]]
    calls = [c for c, _ in made]
    calls[1] = {**calls[1], "quats": calls[1]["quats"][:-1]}  # one row short
    results = rasterization_many(calls, threads=2)
    assert isinstance(results[1], InputError)
    assert str(results[1]).startswith("scene 1: quats must have shape")
    for k in (0, 2):
        render, alpha, _ = rasterization(**scene_call(*SCENES[k])[0], threads=1)
        assert bits(results[k][0]) == bits(render) and bits(results[k][1]) == bits(alpha)


def test_the_core_returns_each_scenes_error_in_its_place():
    call, _ = scene_call(*SCENES[0])
    arrays = {k: call[k].detach().numpy() for k in NAMES}
    good = {**arrays, "viewmats": call["viewmats"].numpy(), "Ks": call["Ks"].numpy(),
            "width": W, "height": H, "sh_degree": 1}  # fmt: skip
    bad_k = good["Ks"].copy()
    bad_k[0, 0, 0] = np.nan  # refused by the core's camera check
    out = _core.rasterize_forward_many([good, {**good, "Ks": bad_k}, {**good, "width": 0}])
    assert isinstance(out[0], dict) and "state" in out[0]
    assert isinstance(out[1], _core.InputError) and isinstance(out[2], _core.InputError)
    alone = native.forward(**good)
    assert out[0]["render"].tobytes() == alone["render"].tobytes()
    v_render, v_alpha = np.ones_like(alone["render"]), np.ones_like(alone["alpha"])
    grads = _core.rasterize_backward_many(
        [out[0]["state"], alone["state"]], [v_render, v_render[..., :1]], [v_alpha, v_alpha]
    )
    assert isinstance(grads[0], dict) and isinstance(grads[1], _core.InputError)
    assert "v_render" in str(grads[1])
    one = native.backward(alone["state"], v_render, v_alpha)
    assert grads[0]["means"].tobytes() == one["means"].tobytes()
    with pytest.raises(_core.InputError, match="one v_render and one v_alpha per state"):
        _core.rasterize_backward_many([alone["state"]], [], [])


def test_a_plant_trains_to_the_same_bytes_alone_and_in_a_group(tmp_path):
    """A plant alone is the batch of one of the group's path: a per-sample guidance (a
    fixed target) gives each plant of a group of three the bits it gets alone."""
    from plant_runs import done, failed, group
    from plantdreamer.guidance.base import PhotometricGuidance
    from plantdreamer.pipeline import GenerateConfig, generate_plants

    def cfg(seed):
        return GenerateConfig.of(species="bean", seed=seed, steps=3, points=500, resolution=32,
                                 eval_views=1, turntable="none")  # fmt: skip

    target = torch.full((1, 32, 32, 3), 0.3)
    together = group([cfg(s) for s in range(3)], tmp_path / "g",
                     guidance=PhotometricGuidance(target), show_progress=False)  # fmt: skip
    assert not failed(together)
    for s in range(3):
        alone = generate_plants([cfg(s)], tmp_path / f"alone{s}",
                                guidance=PhotometricGuidance(target), show_progress=False)[0]  # fmt: skip
        ply = done(together)[f"bean-s{s:04d}"].ply_path.read_bytes()
        assert ply == alone.ply_path.read_bytes(), s
