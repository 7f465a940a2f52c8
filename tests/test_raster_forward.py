"""Forward rasterizer against the dense float64 reference, closed forms and the contract."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest
import torch

import raster_native as native
import raster_reference as ref
from plantdreamer import InputError, _core, rasterization

W = H = 72


def assert_image_close(native: torch.Tensor, reference: torch.Tensor, what: str) -> None:
    err = (native.double() - reference).abs().flatten()
    p999 = torch.quantile(err, 0.999).item()
    mean = err.mean().item()
    assert p999 <= 1e-4, f"{what}: 99.9th percentile error {p999:.3g}"
    assert mean <= 1e-5, f"{what}: mean error {mean:.3g}"


def render_reference(scene, viewmats, ks, i, **kw):
    return ref.render(
        *[x.double() for x in scene], viewmats[i].double(), ks[i].double(), W, H, **kw
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize(
    ("sh_degree", "mode", "aa"),
    [(None, "RGB+D", False), (3, "RGB+D", False), (1, "RGB", True), (2, "D", False)],
)
def test_matches_dense_reference_on_plant_scenes(seed, sh_degree, mode, aa):
    scene = ref.plant_scene(seed, n=400, sh_degree=sh_degree)
    viewmats, ks = ref.scene_cameras(W, H, n=2)
    colors, alphas, meta = rasterization(
        *scene,
        viewmats,
        ks,
        W,
        H,
        sh_degree=sh_degree,
        render_mode=mode,
        rasterize_mode="antialiased" if aa else "classic",
    )
    assert colors.shape == (2, H, W, {"RGB+D": 4, "RGB": 3, "D": 1}[mode])
    assert alphas.shape == (2, H, W, 1)
    for i in range(2):
        want, want_alpha = render_reference(
            scene,
            viewmats,
            ks,
            i,
            sh_degree=sh_degree,
            with_color=mode != "D",
            with_depth=mode.endswith("D"),
            antialiased=aa,
        )
        # The scenes are busy: most pixels see several overlapping splats.
        assert (want_alpha > 0.5).double().mean().item() > 0.12
        if mode != "D":
            assert_image_close(colors[i, ..., :3], want[..., :3], "rgb")
        if mode.endswith("D"):
            assert_image_close(colors[i, ..., -1], want[..., -1], "depth")
        assert_image_close(alphas[i, ..., 0], want_alpha, "alpha")
        assert meta["n_visible"][i] > 300
        assert meta["n_intersections"][i] >= meta["n_visible"][i]


def test_expected_depth_and_background():
    scene = ref.plant_scene(5, n=200)
    viewmats, ks = ref.scene_cameras(W, H)
    bg = torch.tensor([[0.2, 0.5, 0.9]])
    colors, _, _ = rasterization(*scene, viewmats, ks, W, H, backgrounds=bg, render_mode="RGB+ED")
    want, want_alpha = render_reference(scene, viewmats, ks, 0, with_depth=True)
    want_rgb = want[..., :3] + bg.double()[0] * (1 - want_alpha[..., None])
    assert_image_close(colors[0, ..., :3], want_rgb, "rgb over background")
    covered = want_alpha > 0.2
    ed = want[..., 3] / want_alpha.clamp_min(1e-10)
    torch.testing.assert_close(
        colors[0, ..., 3][covered].double(), ed[covered], atol=1e-4, rtol=1e-5
    )


def test_single_gaussian_matches_closed_form():
    # A rotated anisotropic Gaussian on the optical axis: the 2D covariance is known exactly.
    f, z, theta = 80.0, 3.0, 0.6
    sx, sy = 0.12, 0.05
    viewmat = torch.eye(4)[None]
    ks = torch.tensor([[[f, 0.0, W / 2], [0.0, f, H / 2], [0.0, 0.0, 1.0]]])
    quat = torch.tensor([[math.cos(theta / 2), 0.0, 0.0, math.sin(theta / 2)]])
    means = torch.tensor([[0.0, 0.0, z]])
    scales = torch.tensor([[sx, sy, 0.02]])
    color = [0.9, 0.4, 0.1]
    img, alpha, meta = rasterization(
        means, quat, scales, torch.tensor([0.8]), torch.tensor([color]), viewmat, ks, W, H
    )
    rot = torch.tensor(
        [[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]],
        dtype=torch.float64,
    )
    cov = rot @ torch.diag(torch.tensor([(f * sx / z) ** 2, (f * sy / z) ** 2])).double() @ rot.T
    cov = cov + 0.3 * torch.eye(2, dtype=torch.float64)
    want, want_alpha = ref.closed_form_single(torch.tensor([W / 2, H / 2]), cov, 0.8, color, W, H)
    torch.testing.assert_close(img[0].double(), want, atol=2e-6, rtol=1e-5)
    torch.testing.assert_close(alpha[0, ..., 0].double(), want_alpha, atol=2e-6, rtol=1e-5)
    # Opacity-aware footprint: the exact box of the alpha = 1/255 contour.
    extent = math.sqrt(2 * math.log(255 * 0.8))
    assert meta["radii"][0, 0].tolist() == [
        math.ceil(extent * math.sqrt(cov[0, 0])),
        math.ceil(extent * math.sqrt(cov[1, 1])),
    ]
    assert meta["means2d"][0, 0].tolist() == [W / 2, H / 2]


def test_sh_matches_direct_formulas():
    g = torch.Generator().manual_seed(3)
    coeffs = torch.randn(500, 16, 3, generator=g)
    dirs = torch.randn(500, 3, generator=g) * torch.rand(500, 1, generator=g) * 10
    for degree in range(4):
        native = _core.eval_sh(degree, coeffs.numpy(), dirs.numpy())
        want = ref.sh_eval(degree, coeffs.double(), dirs.double())
        np.testing.assert_allclose(native, want.numpy(), atol=2e-5, rtol=1e-5)


def test_reference_sh_basis_is_orthonormal():
    # Gauss-Legendre in cos(theta) x uniform phi integrates these degree <= 6 products exactly.
    x, w = np.polynomial.legendre.leggauss(8)
    phi = np.arange(16) * 2 * np.pi / 16
    ct, ph = np.meshgrid(x, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    d = torch.from_numpy(np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3))
    weights = torch.from_numpy((w[:, None] * np.full(16, 2 * np.pi / 16)).reshape(-1))
    b = ref.sh_basis(3, d)
    gram = (b * weights[:, None]).T @ b
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=1e-12, rtol=0)


def native_forward(scene, viewmats, ks, **kw):
    return native.forward(
        *[x.numpy() for x in scene], viewmats.numpy(), ks.numpy(), W, H, render_depth=True, **kw
    )


def test_bit_identical_for_one_and_two_threads():
    scene = ref.plant_scene(7, n=3000, sh_degree=3)
    viewmats, ks = ref.scene_cameras(W, H, n=2)
    one = native_forward(scene, viewmats, ks, sh_degree=3, threads=1)
    two = native_forward(scene, viewmats, ks, sh_degree=3, threads=2)
    for key in ("render", "alpha", "radii", "means2d", "depths", "n_intersections"):
        assert np.array_equal(one[key], two[key]), key
    again = native_forward(scene, viewmats, ks, sh_degree=3, threads=2)
    assert np.array_equal(one["render"], again["render"])


@pytest.mark.parametrize("tile_size", [16, 13, 40])
def test_simd_and_scalar_kernels_give_the_same_bits(tile_size):
    # The AVX2 kernel (on CPUs that have it) and the scalar one: same operations, same order.
    scene = ref.plant_scene(9, n=3000, sh_degree=2)
    viewmats, ks = ref.scene_cameras(W, H, n=2)
    fast = native_forward(scene, viewmats, ks, sh_degree=2, tile_size=tile_size)
    slow = native_forward(scene, viewmats, ks, sh_degree=2, tile_size=tile_size, simd=False)
    assert (fast["alpha"] > 0.5).mean() > 0.05  # the scene covers part of the image
    for key in ("render", "alpha"):
        assert np.array_equal(fast[key], slow[key]), key


def test_defaults_are_the_cores_in_the_binding_and_in_python():
    defaults = _core.raster_defaults()
    assert set(defaults) == {
        "near_plane",
        "far_plane",
        "eps2d",
        "antialiased",
        "render_depth",
        "tile_size",
        "footprint_sigma",
        "tile_ellipse",
        "t_min",
        "simd",
    }
    # Python's signature shows the core's values.
    params = inspect.signature(rasterization).parameters
    for key in ("near_plane", "far_plane", "eps2d", "tile_size"):
        assert params[key].default == defaults[key], key
    mode = "antialiased" if defaults["antialiased"] else "classic"
    assert params["rasterize_mode"].default == mode
    # The binding fills a keyword left out with the same values: the same bits either way.
    scene = ref.plant_scene(3, n=500, sh_degree=1)
    viewmats, ks = ref.scene_cameras(W, H, n=1)
    explicit = {k: v for k, v in defaults.items() if k != "render_depth"}
    implicit_out = native_forward(scene, viewmats, ks, sh_degree=1)
    explicit_out = native_forward(scene, viewmats, ks, sh_degree=1, **explicit)
    assert np.array_equal(implicit_out["render"], explicit_out["render"])
    # ... and the keyword is used (a changed value changes the image).
    blurred = native_forward(scene, viewmats, ks, sh_degree=1, eps2d=4 * defaults["eps2d"] + 1)
    assert not np.array_equal(implicit_out["render"], blurred["render"])
    # The wrapper passes its defaults explicitly and renders the same image.
    colors, _, _ = rasterization(*scene, viewmats, ks, W, H, sh_degree=1, render_mode="RGB+D")
    assert np.array_equal(colors[0].numpy(), implicit_out["render"][0])


def test_info_names_the_blending_kernel():
    assert _core.info()["blend_kernel"] in ("avx2", "scalar")


@pytest.mark.parametrize("tile_size", [8, 32, 5])
def test_tile_size_and_ellipse_test_do_not_change_the_image(tile_size):
    # Every pixel blends the same splats in the same order with the same arithmetic, so the
    # image is the same to the bit.
    scene = ref.plant_scene(8, n=600)
    viewmats, ks = ref.scene_cameras(W, H)
    base = native_forward(scene, viewmats, ks)
    other = native_forward(scene, viewmats, ks, tile_size=tile_size, tile_ellipse=False)
    assert np.array_equal(other["render"], base["render"])
    assert np.array_equal(other["alpha"], base["alpha"])
    if tile_size == 8:
        with_ellipse = native_forward(scene, viewmats, ks, tile_size=8)
        assert with_ellipse["n_intersections"][0] < other["n_intersections"][0]


def test_outputs_are_float32_cpu_and_meta_is_complete():
    scene = ref.plant_scene(9, n=50)
    viewmats, ks = ref.scene_cameras(W, H)
    colors, alphas, meta = rasterization(*scene, viewmats, ks, W, H)
    assert colors.dtype == alphas.dtype == torch.float32
    assert meta["radii"].dtype == torch.int32 and meta["radii"].shape == (1, 50, 2)
    assert meta["means2d"].shape == (1, 50, 2) and not meta["means2d"].requires_grad
    assert meta["depths"].shape == (1, 50)
    assert meta["n_visible"].tolist() == [int((meta["radii"][0] > 0).any(-1).sum())]
    assert set(meta) >= {"n_intersections", "width", "height", "tile_size", "profile"}


def test_culled_gaussians_have_zero_radii():
    scene = ref.plant_scene(10, n=20)
    means = scene[0].clone()
    means[3] = torch.tensor([0.0, 0.0, 100.0])  # far behind the camera (orbit at distance 2.2)
    means[4] = torch.tensor([float("nan"), 0.0, 0.0])
    viewmats, ks = ref.scene_cameras(W, H)
    # camera looks at the origin from +x side; push one Gaussian behind it
    cam_centre = torch.linalg.inv(viewmats[0].double())[:3, 3].float()
    means[3] = cam_centre * 2
    opac = scene[3].clone()
    opac[5] = 0.5 / 255
    quats = scene[1].clone()
    quats[6] = 0.0
    _, _, meta = rasterization(means, quats, scene[2], opac, scene[4], viewmats, ks, W, H)
    radii = meta["radii"][0]
    for i in (3, 4, 5, 6):
        assert radii[i].tolist() == [0, 0], i
    assert (radii[[0, 1, 2]] > 0).all()


def test_nan_gaussian_is_culled_not_poisoning_the_image():
    scene = ref.plant_scene(11, n=100)
    viewmats, ks = ref.scene_cameras(W, H)
    clean, clean_alpha, _ = rasterization(*scene, viewmats, ks, W, H)
    bad = [x.clone() for x in scene]
    extra = [
        torch.tensor([[0.0, 0.0, 0.0]]),
        torch.tensor([[1.0, 0.0, 0.0, 0.0]]),
        torch.tensor([[float("inf"), 0.1, 0.1]]),
        torch.tensor([0.9]),
        torch.tensor([[float("nan"), 0.0, 0.0]]),
    ]
    bad = [torch.cat([x, e]) for x, e in zip(bad, extra, strict=True)]
    img, alpha, meta = rasterization(*bad, viewmats, ks, W, H)
    assert torch.equal(img, clean) and torch.equal(alpha, clean_alpha)
    assert meta["radii"][0, -1].tolist() == [0, 0]


def test_empty_scene_renders_background_and_no_cameras_is_empty():
    viewmats, ks = ref.scene_cameras(W, H, n=2)
    e3, e4 = torch.zeros(0, 3), torch.zeros(0, 4)
    bg = torch.tensor([[0.1, 0.2, 0.3], [1.0, 1.0, 1.0]])
    img, alpha, meta = rasterization(
        e3, e4, e3, torch.zeros(0), e3, viewmats, ks, W, H, backgrounds=bg
    )
    assert img.shape == (2, H, W, 3)
    assert torch.equal(img, bg[:, None, None, :].expand(2, H, W, 3))
    assert alpha.abs().max() == 0 and meta["n_visible"].tolist() == [0, 0]
    scene = ref.plant_scene(0, n=10)
    img, alpha, meta = rasterization(*scene, viewmats[:0], ks[:0], W, H, render_mode="RGB+D")
    assert img.shape == (0, H, W, 4) and alpha.shape == (0, H, W, 1)
    assert meta["radii"].shape == (0, 10, 2)


def test_non_contiguous_inputs_are_accepted():
    scene = ref.plant_scene(12, n=64)
    viewmats, ks = ref.scene_cameras(W, H)
    want, _, _ = rasterization(*scene, viewmats, ks, W, H)
    means_t = scene[0].T.contiguous().T  # same values, transposed strides
    assert not means_t.is_contiguous()
    got, _, _ = rasterization(means_t, *scene[1:], viewmats, ks, W, H)
    assert torch.equal(got, want)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda a: a.update(means=a["means"].double()), "means must be float32"),
        (lambda a: a.update(quats=a["quats"][:, :3]), "quats must have shape"),
        (lambda a: a.update(opacities=a["opacities"][:, None]), "opacities must have shape"),
        (lambda a: a.update(colors=a["colors"][:-1]), "colors must have shape"),
        (lambda a: a.update(Ks=a["Ks"][:, :2]), "Ks must have shape"),
        (lambda a: a.update(viewmats=a["viewmats"] * float("nan")), "finite"),
        (lambda a: a.update(render_mode="RGBD"), "render_mode"),
        (lambda a: a.update(rasterize_mode="fast"), "rasterize_mode"),
        (lambda a: a.update(sh_degree=4), "sh_degree"),
        (lambda a: a.update(sh_degree=1), "colors \\(SH"),
        (lambda a: a.update(width=0), "image size"),
        (lambda a: a.update(tile_size=1), "tile_size"),
        (lambda a: a.update(near_plane=-1.0), "near_plane"),
        (lambda a: a.update(backgrounds=torch.zeros(2, 3)), "backgrounds must have shape"),
        (lambda a: a.update(means=[[0.0, 0.0, 0.0]]), "torch tensor"),
    ],
)
def test_bad_inputs_raise_input_error(change, message):
    scene = ref.plant_scene(13, n=8)
    viewmats, ks = ref.scene_cameras(W, H)
    names = ("means", "quats", "scales", "opacities", "colors")
    args = dict(zip(names, scene, strict=True), viewmats=viewmats, Ks=ks, width=W, height=H)
    change(args)
    with pytest.raises(InputError, match=message):
        rasterization(**args)


def test_native_rejects_wrong_dtype_and_layout():
    scene = ref.plant_scene(14, n=8)
    viewmats, ks = ref.scene_cameras(W, H)
    arrays = [x.numpy() for x in scene]
    with pytest.raises(InputError, match="float32"):
        native.forward(
            arrays[0].astype(np.float64), *arrays[1:], viewmats.numpy(), ks.numpy(), W, H
        )
    with pytest.raises(InputError, match="contiguous"):
        native.forward(
            np.asfortranarray(arrays[0]), *arrays[1:], viewmats.numpy(), ks.numpy(), W, H
        )


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_inputs_round_trip():  # pragma: no cover - no GPU on CI
    scene = [x.cuda() for x in ref.plant_scene(15, n=30)]
    viewmats, ks = ref.scene_cameras(W, H)
    img, _, _ = rasterization(*scene, viewmats.cuda(), ks.cuda(), W, H)
    assert img.device.type == "cuda"
