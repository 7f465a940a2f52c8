"""Depth-map cleaning for the ControlNet, on synthetic depth maps, and the per-pose cache."""

import numpy as np
import pytest
import torch

from plantdreamer.cameras import orbit
from plantdreamer.errors import InputError
from plantdreamer.guidance.depth import (
    DepthCleaning,
    DepthConditioner,
    clean_depth,
    dilate,
    erode,
    kernel_size,
    max_filter,
    normalise_depth,
    quantile,
    save_depth_png,
)

SIZE = 96
CENTRE = 48


def synthetic_plant():
    """[1, H, W, 1] expected depth and alpha of a disc-shaped 'plant' with typical defects.

    Depth grows left to right (3.0 .. 3.4); a half-transparent halo ring sits around it at
    a wrong depth; a 1-pixel spur sticks out; a few opaque far floaters sit at depth 20.
    """
    yy, xx = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    r = np.hypot(yy - CENTRE, xx - CENTRE)
    depth = np.zeros((SIZE, SIZE))
    alpha = np.zeros((SIZE, SIZE))
    disc = r < 20
    depth[disc] = 3.0 + 0.01 * (xx[disc] - (CENTRE - 20))
    alpha[disc] = 1.0
    halo = (r >= 20) & (r < 23)
    depth[halo], alpha[halo] = 5.0, 0.3
    depth[CENTRE, 70:90], alpha[CENTRE, 70:90] = 3.2, 1.0  # thin spur
    depth[10, 10:14], alpha[10, 10:14] = 20.0, 1.0  # far floaters (4 px of ~1250)
    as_t = lambda a: torch.tensor(a, dtype=torch.float32)[None, ..., None]  # noqa: E731
    return as_t(depth), as_t(alpha), disc


def reference_filter(image: np.ndarray, k: int, op) -> np.ndarray:
    """Slow min/max filter over the k x k window clipped at the border."""
    h, w = image.shape
    out = np.empty_like(image)
    for i in range(h):
        for j in range(w):
            win = image[max(0, i - k // 2) : i + k // 2 + 1, max(0, j - k // 2) : j + k // 2 + 1]
            out[i, j] = op(win)
    return out


@pytest.mark.parametrize("k", [1, 3, 5, 9])
def test_morphology_matches_slow_reference(k):
    image = torch.rand(1, 1, 17, 23, generator=torch.Generator().manual_seed(k))
    np.testing.assert_array_equal(
        erode(image, k)[0, 0].numpy(), reference_filter(image[0, 0].numpy(), k, np.min)
    )
    np.testing.assert_array_equal(
        dilate(image, k)[0, 0].numpy(), reference_filter(image[0, 0].numpy(), k, np.max)
    )


@pytest.mark.parametrize("k", [3, 5, 7, 13])
def test_max_filter_equals_max_pooling(k):
    """The row and column passes give max_pool2d's values exactly (batch, channels, edges
    wider than the image, ties and infinities included)."""
    g = torch.Generator().manual_seed(k)
    image = torch.randint(0, 4, (2, 3, 11, 6), generator=g).float()  # many ties
    image[0, 0, 0, 0], image[1, 2, 5, 3] = float("inf"), float("-inf")
    pooled = torch.nn.functional.max_pool2d(image, k, stride=1, padding=k // 2)
    assert torch.equal(max_filter(image, k), pooled)


def bits(t: torch.Tensor) -> bytes:
    return t.contiguous().numpy().tobytes()


def whole_map_normalise(depth, alpha, config):
    """Steps 1-3 as plainly written (torch.isfinite, torch's boolean index, torch.quantile):
    the reference ``normalise_depth`` must give bit for bit."""
    mask = (alpha > config.alpha_threshold) & torch.isfinite(depth) & (depth > 0)
    values = depth[mask].double()
    near = values.min()
    far = torch.quantile(values, config.far_quantile)
    keep = mask & (depth <= far.to(depth.dtype))
    span = float(far - near)
    if span <= 1e-12:
        n = torch.ones_like(depth)
    else:
        n = ((far - depth.double()) / span).clamp(0.0, 1.0).to(depth.dtype)
    floor = config.min_intensity * config.intensity_scale
    if config.rule == "stretch-lift":
        mapped = ((n + config.min_intensity) * config.intensity_scale).clamp(max=1.0)
    else:
        mapped = floor + (1.0 - floor) * n
    return torch.where(keep, mapped, torch.zeros_like(mapped))


@pytest.mark.parametrize("rule", ["stretch", "stretch-lift"])
def test_normalisation_has_the_bits_of_the_plain_formulation(rule):
    d, a, _ = synthetic_plant()
    d, a = d[0, ..., 0], a[0, ..., 0]
    g = torch.Generator().manual_seed(3)
    noisy = d + torch.rand(d.shape, generator=g) * (d > 0)  # many distinct depths
    broken = noisy.clone()  # opaque pixels with no finite depth, or none in front
    broken[40, 30:36] = torch.tensor([float("nan"), float("inf"), -float("inf"), -1.0, 0.0, -0.0])
    cfg = DepthCleaning(rule=rule)
    for depth in (d, noisy, broken, torch.where(a > 0.5, 3.0, d)):  # the last: a flat plant
        got = normalise_depth(depth, a, cfg)
        assert bits(got) == bits(whole_map_normalise(depth, a, cfg)) and bool((got > 0).any())
    # Strided views (a transposed map; the [H, W] slice of a [B, H, W, 1] batch).
    got = normalise_depth(noisy.t(), a.t(), cfg)
    assert bits(got) == bits(whole_map_normalise(noisy.t(), a.t(), cfg))
    batch = torch.stack([d, noisy])[..., None]
    got = normalise_depth(batch[1, ..., 0], torch.stack([a, a])[..., None][1, ..., 0], cfg)
    assert bits(got) == bits(whole_map_normalise(noisy, a, cfg))


@pytest.mark.parametrize("k", [3, 5, 7])
def test_erosion_has_the_bits_of_the_negated_pooling_of_the_negated_map(k):
    """On the maps clean_depth erodes (finite, +0 background, positive plant) the minimum
    filter gives the bits the former -max(-x) did, signed zeros included."""
    d, a, _ = synthetic_plant()
    image = normalise_depth(d[0, ..., 0], a[0, ..., 0], DepthCleaning())[None, None]
    g = torch.Generator().manual_seed(k)
    speckled = torch.rand(2, 1, 31, 40, generator=g) * (torch.rand(2, 1, 31, 40, generator=g) > 0.3)
    for x in (image, speckled):
        pooled = -torch.nn.functional.max_pool2d(-x, k, stride=1, padding=k // 2)
        assert bits(erode(x, k)) == bits(pooled)


def test_normalisation_near_is_bright_and_background_halo_and_tail_are_removed():
    depth, alpha, disc = synthetic_plant()
    n = normalise_depth(depth[0, ..., 0], alpha[0, ..., 0], DepthCleaning()).numpy()
    assert n.min() >= 0.0 and n.max() <= 1.0
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    r = np.hypot(yy - CENTRE, xx - CENTRE)
    halo = (r >= 20) & (r < 23)
    halo[CENTRE] = False  # the spur crosses the halo on this row
    assert (n[halo] == 0).all(), "half-transparent halo must be removed"
    assert (n[10, 10:14] == 0).all(), "far floaters must be removed"
    assert (n[0:5, :] == 0).all(), "background must be 0"
    row = n[CENTRE, CENTRE - 19 : CENTRE + 19]
    assert (np.diff(row) <= 0).all() and row[0] > row[-1], "nearer (left) must be brighter"
    # Released-code contrast lift: the nearest pixel saturates, the farthest is 0.175.
    assert n[disc].max() == pytest.approx(1.0)
    assert n[disc].min() == pytest.approx(0.1 * 1.75, abs=1e-3)


@pytest.mark.parametrize("n", [1, 2, 3, 101, 4097, 100_003])
def test_quantile_is_torch_quantile_bit_for_bit(n):
    g = torch.Generator().manual_seed(n)
    spread = 1.0 + 4.0 * torch.rand(n, generator=g, dtype=torch.float64)
    ties = torch.round(spread * 10) / 10
    flat = torch.full((n,), 2.5, dtype=torch.float64)
    for values in (spread, ties, flat):
        for q in (0.0, 0.25, 0.5, 0.9, 0.99, 0.999, 1 / 3, 1.0):
            want = torch.quantile(values, q)
            got = quantile(values, q)
            assert got.dtype == want.dtype and got.shape == want.shape
            assert got.item() == want.item(), (n, q)


def test_normalisation_is_the_same_map_as_with_torch_quantile(monkeypatch):
    from plantdreamer.guidance import depth as depth_module

    d, a, _ = synthetic_plant()
    cfg = DepthCleaning()
    fast = normalise_depth(d[0, ..., 0], a[0, ..., 0], cfg)
    monkeypatch.setattr(depth_module, "quantile", torch.quantile)
    slow = normalise_depth(d[0, ..., 0], a[0, ..., 0], cfg)
    assert torch.equal(fast, slow) and bool((fast > 0).any())


def test_accumulated_depth_gives_the_same_map():
    depth, alpha, _ = synthetic_plant()
    a = clean_depth(depth, alpha, 4.0, out_size=SIZE)
    b = clean_depth(depth * alpha, alpha, 4.0, out_size=SIZE, accumulated=True)
    torch.testing.assert_close(a, b)


def test_opening_removes_thin_spur_and_keeps_the_body():
    depth, alpha, disc = synthetic_plant()
    raw = clean_depth(depth, alpha, 4.0, out_size=SIZE, erode=False, dilate=False)[0, 0]
    opened = clean_depth(depth, alpha, 4.0, out_size=SIZE, kernel_reference_size=SIZE)[0, 0]
    assert (raw[CENTRE, 75:90] > 0).all()
    assert (opened[CENTRE, 75:90] == 0).all(), "the 1-px spur survives the opening"
    # Opening keeps the interior (away from the depth gradient's 1-px steps) and the extent.
    inner = torch.tensor(np.hypot(*np.mgrid[-CENTRE : SIZE - CENTRE, -CENTRE : SIZE - CENTRE]) < 15)
    torch.testing.assert_close(opened[inner], raw[inner], atol=0.03, rtol=0)
    assert abs(int((opened > 0).sum()) - int(disc.sum())) < 0.1 * disc.sum()
    # Erosion alone (the released code) shrinks the plant.
    eroded = clean_depth(
        depth, alpha, 4.0, out_size=SIZE, dilate=False, kernel_reference_size=SIZE
    )[0, 0]
    assert (eroded > 0).sum() < 0.9 * (opened > 0).sum()


def test_output_is_resized_and_in_unit_range():
    depth, alpha, _ = synthetic_plant()
    out = clean_depth(depth.repeat(2, 1, 1, 1), alpha.repeat(2, 1, 1, 1), [3.0, 6.0], out_size=64)
    assert out.shape == (2, 1, 64, 64)
    assert out.min() >= 0 and out.max() <= 1
    assert out[:, :, :5].abs().max() == 0


@pytest.mark.parametrize(
    ("distance", "size", "k"),
    [
        (1.5, 768, 3),
        (3.0, 768, 5),
        (4.99, 768, 5),
        (5.0, 768, 7),
        (6.0, 768, 7),
        (6.0, 512, 5),
        (3.0, 512, 3),
        (6.0, 64, 1),
    ],
)
def test_kernel_from_camera_distance(distance, size, k):
    assert kernel_size(distance, size, DepthCleaning()) == k


def test_kernel_is_not_the_released_code_bug():
    # The released code picks the kernel from ||c2w||_F = sqrt(4 + r^2): r = 4.8 -> 5.18 -> 7 px.
    assert kernel_size(4.8, 768, DepthCleaning()) == 5


def test_empty_view_gives_zeros():
    out = clean_depth(torch.zeros(1, 8, 8, 1), torch.zeros(1, 8, 8, 1), 4.0, out_size=8)
    assert torch.equal(out, torch.zeros(1, 1, 8, 8))


def test_flat_plant_is_fully_bright():
    out = clean_depth(torch.full((1, 8, 8, 1), 2.0), torch.ones(1, 8, 8, 1), 4.0, out_size=8)
    assert torch.equal(out, torch.ones(1, 1, 8, 8))


def test_bad_arguments():
    d = torch.ones(1, 8, 8, 1)
    with pytest.raises(InputError):
        clean_depth(d, torch.ones(1, 8, 8, 2), 4.0)
    with pytest.raises(InputError):
        clean_depth(d, d, [4.0, 5.0])
    with pytest.raises(InputError):  # a list gives each map its own: one short is refused
        clean_depth(d.repeat(2, 1, 1, 1), d.repeat(2, 1, 1, 1), [4.0])
    with pytest.raises(InputError):
        clean_depth(d, d, 0.0)
    with pytest.raises(InputError):
        clean_depth(d, d, 4.0, far_quantile=0.0)
    with pytest.raises(TypeError):
        clean_depth(d, d, 4.0, no_such_parameter=1)


def test_conditioner_renders_each_pose_once_and_evicts_oldest():
    depth, alpha, _ = synthetic_plant()
    calls = []

    def render(camera):
        calls.append(camera)
        return depth[0], alpha[0]

    cond = DepthConditioner(render, cache_size=2, out_size=32)
    a, b, c = (orbit(4.0, 15.0, az, 60.0, SIZE, SIZE) for az in (0.0, 90.0, 180.0))
    out = cond([a, b, a])
    assert out.shape == (3, 1, 32, 32)
    assert len(calls) == 2 and cond.hits == 1
    assert torch.equal(out[0], out[2])
    # LRU order is now b, a. Rendering c evicts b; a stays cached.
    cond([c])
    assert len(calls) == 3
    cond([a])
    assert len(calls) == 3
    cond([b])  # re-rendered; evicts c (order was c, a)
    assert len(calls) == 4
    # The same pose rebuilt from scratch hits the cache.
    cond([orbit(4.0, 15.0, 0.0, 60.0, SIZE, SIZE)])
    assert len(calls) == 4
    cond([c])
    assert len(calls) == 5


def test_conditioner_uses_camera_distance_for_the_kernel():
    depth, alpha, _ = synthetic_plant()
    cond = DepthConditioner(
        lambda cam: (depth[0], alpha[0]), out_size=SIZE, kernel_reference_size=SIZE, dilate=False
    )
    near = cond([orbit(1.0, 15.0, 0.0, 60.0, SIZE, SIZE)])  # 3 px kernel
    far = cond([orbit(9.0, 15.0, 0.0, 60.0, SIZE, SIZE)])  # 7 px kernel
    assert (far > 0).sum() < (near > 0).sum()  # erosion with the larger kernel


def test_example_conditioning_images_are_saved(tmp_path):
    """Artifact for a person to look at: raw depth, normalised, and cleaned."""
    depth, alpha, _ = synthetic_plant()
    raw = (depth[..., 0] / depth.max())[:, None]
    paths = [
        save_depth_png(raw[0], tmp_path / "depth_raw.png"),
        save_depth_png(
            clean_depth(depth, alpha, 4.0, out_size=512, erode=False, dilate=False),
            tmp_path / "depth_normalised.png",
        ),
        save_depth_png(
            clean_depth(depth, alpha, 4.0, out_size=512, kernel_reference_size=SIZE),
            tmp_path / "depth_cleaned.png",
        ),
    ]
    print("depth conditioning examples:", *paths)
    from PIL import Image

    for p in paths:
        with Image.open(p) as im:
            assert im.mode == "L"
    with Image.open(paths[2]) as im:
        assert im.size == (512, 512)
        assert np.asarray(im)[256, 180] > np.asarray(im)[256, 340] > 0


@pytest.mark.parametrize(("depth_size", "rendered"), [("sds", 32), ("render", SIZE)])
def test_the_depth_map_is_rendered_at_the_sds_size_or_at_the_render_size(depth_size, rendered):
    depth, alpha, _ = synthetic_plant()
    seen = []

    def render(camera):
        seen.append(camera)
        return depth[0], alpha[0]

    cond = DepthConditioner(render, out_size=32, depth_size=depth_size)
    camera = orbit(4.0, 15.0, 0.0, 60.0, SIZE, SIZE)
    assert cond([camera]).shape == (1, 1, 32, 32)
    assert (seen[0].width, seen[0].height) == (rendered, rendered)
    assert np.array_equal(seen[0].viewmat, camera.viewmat)
    cond([orbit(4.0, 15.0, 0.0, 60.0, SIZE, SIZE)])  # cached by the training camera
    assert len(seen) == 1
    with pytest.raises(InputError, match="depth size"):
        DepthConditioner(render, depth_size="half")
