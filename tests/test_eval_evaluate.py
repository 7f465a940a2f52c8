"""End to end: render a model at known cameras, write a dataset, evaluate the model on it.

Runs with the dense reference renderer now, and with the project rasterizer
(``plantdreamer.rasterization``) once it is part of the build.
"""

import json

import numpy as np
import pytest
from PIL import Image

from eval_synthetic import (
    perturbed,
    render_dense,
    synthetic_plant,
    write_transforms_dataset,
)
from plantdreamer.cameras import orbit_ring
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.eval import PSNR_MAX_DB, evaluate, load_dataset
from plantdreamer.eval.evaluate import render_view
from plantdreamer.gaussians import Gaussians, rgb_to_sh_dc

BG = (0.75, 0.75, 0.75)

RENDERERS = [
    pytest.param(render_dense, id="reference"),
    pytest.param(None, id="rasterization"),
]


def _render(renderer):
    return renderer or render_view


def _cameras(n=4, size=64):
    return orbit_ring(n, 3.2, 20.0, 50.0, size, size)


@pytest.mark.slow
@pytest.mark.parametrize("renderer", RENDERERS)
def test_same_model_scores_high_and_perturbed_model_lower(tmp_path, renderer):
    plant = synthetic_plant()
    write_transforms_dataset(tmp_path, plant, _cameras(), _render(renderer), BG)
    frames = load_dataset(tmp_path)
    assert len(frames) == 4 and all(f.mask is not None and f.mask.any() for f in frames)
    same = evaluate(plant, frames, BG, render=renderer)
    mean = same.mean
    assert mean["masked_psnr"] > 40.0 and mean["psnr"] > 40.0
    assert mean["mask_iou"] > 0.99
    assert mean["masked_ssim"] > 0.99
    worse = evaluate(perturbed(plant), frames, BG, render=renderer).mean
    assert worse["masked_psnr"] < mean["masked_psnr"] - 10.0
    assert worse["mask_iou"] < mean["mask_iou"] - 0.05
    assert worse["masked_ssim"] < mean["masked_ssim"]
    assert len(same.views) == 4 and same.counts()["masked_psnr"] == 4


@pytest.mark.slow
@pytest.mark.parametrize("renderer", RENDERERS)
def test_rgba_dataset_is_composited_over_the_background(tmp_path, renderer):
    plant = synthetic_plant()
    write_transforms_dataset(tmp_path, plant, _cameras(2), _render(renderer), BG, rgba=True)
    frames = load_dataset(tmp_path)
    assert all(f.alpha is not None for f in frames)
    for bg in (BG, (0.1, 0.2, 0.9)):
        assert evaluate(plant, frames, bg, render=renderer).mean["psnr"] > 40.0


@pytest.mark.parametrize("renderer", RENDERERS)
def test_gaussian_at_a_known_point_lands_at_the_predicted_pixel(tmp_path, renderer):
    # One small opaque Gaussian at p, camera from transforms.json (OpenGL c2w): its brightest
    # pixel is the one containing the projection predicted by hand from the convention.
    p = np.array([0.4, -0.3, 0.25])
    g = Gaussians(
        p[None].astype(np.float32),
        np.float32([[1, 0, 0, 0]]),
        np.full((1, 3), np.log(0.01), np.float32),
        np.float32([4.0]),
        rgb_to_sh_dc(np.float32([[1, 1, 1]]))[:, None],
    )
    c2w = np.eye(4)
    c2w[:3, 3] = [0.0, 0.0, 4.0]  # at (0, 0, 4) looking down -z, image y = world +y up
    Image.fromarray(np.zeros((48, 64, 3), np.uint8)).save(tmp_path / "v.png")
    meta = {
        "fl_x": 80.0,
        "fl_y": 80.0,
        "cx": 32.0,
        "cy": 24.0,
        "frames": [{"file_path": "v.png", "transform_matrix": c2w.tolist()}],
    }
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    cam = load_dataset(tmp_path)[0].camera
    depth = 4.0 - p[2]
    u, v = 32.0 + 80.0 * p[0] / depth, 24.0 - 80.0 * p[1] / depth
    _, alpha = _render(renderer)(g, cam, (0.0, 0.0, 0.0))
    row, col = np.unravel_index(np.argmax(alpha), alpha.shape)
    assert (col, row) == (int(u), int(v))


def test_evaluate_bookkeeping_with_a_fake_renderer(tmp_path):
    # A renderer that returns each frame's ground truth exactly, except one corrupted frame.
    plant = synthetic_plant()
    cams = _cameras(5, 32)
    write_transforms_dataset(tmp_path, plant, cams, render_dense, BG)
    frames = load_dataset(tmp_path)
    frames[3].mask = None  # a frame without a mask: masked metrics n/a, excluded from means
    by_cam = {id(f.camera): f for f in frames}

    def fake(_g, camera, background):
        f = by_cam[id(camera)]
        rgb = f.ground_truth(background).copy()
        if f.name == "view_001":
            rgb[:] = 0.0
        return rgb, (f.mask if f.mask is not None else np.ones(rgb.shape[:2])).astype(np.float32)

    seen = []
    result = evaluate(
        plant, frames, BG, render=fake, keep_views=2, on_frame=lambda i, m: seen.append(i)
    )
    assert seen == [0, 1, 2, 3, 4]
    names = [m.name for m in result.frames]
    assert names == [f"view_{i:03d}" for i in range(5)]
    assert result.frames[0].psnr == PSNR_MAX_DB and result.frames[0].mask_iou == 1.0
    assert result.frames[1].masked_psnr < 20.0
    assert result.frames[3].masked_psnr is None and result.frames[3].mask_iou is None
    counts = result.counts()
    assert counts["masked_psnr"] == 4 and counts["psnr"] == 5
    expected = np.mean([m.masked_psnr for m in result.frames if m.masked_psnr is not None])
    assert result.mean["masked_psnr"] == pytest.approx(expected)
    assert [v.metrics.name for v in result.views] == ["view_000", "view_004"]
    data = result.to_dict()
    json.dumps(data, allow_nan=False)
    assert data["frames"][3]["masked_psnr"] is None


def test_evaluate_rejects_bad_input_and_bad_renders(tmp_path):
    plant = synthetic_plant()
    write_transforms_dataset(tmp_path, plant, _cameras(1, 16), render_dense, BG)
    frames = load_dataset(tmp_path)
    with pytest.raises(InputError, match="no frames"):
        evaluate(plant, [], BG, render=render_dense)
    with pytest.raises(InputError, match="background"):
        evaluate(plant, frames, (1.0, 0.0), render=render_dense)

    def nan_render(_g, cam, _bg):
        return np.full((cam.height, cam.width, 3), np.nan, np.float32), np.zeros(
            (cam.height, cam.width), np.float32
        )

    with pytest.raises(PlantDreamerError, match="NaN"):
        evaluate(plant, frames, BG, render=nan_render)

    def wrong_size(_g, cam, _bg):
        return np.zeros((4, 4, 3), np.float32), np.zeros((4, 4), np.float32)

    with pytest.raises(PlantDreamerError, match="renderer returned"):
        evaluate(plant, frames, BG, render=wrong_size)
