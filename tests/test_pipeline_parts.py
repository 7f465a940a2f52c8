"""Pipeline pieces that need no renderer: config, culling, checkpoints, Adam bookkeeping,
densification."""

import dataclasses

import numpy as np
import pytest
import torch

from plantdreamer.errors import CheckpointError, InputError
from plantdreamer.pipeline.model.culling import large_gaussian_mask
from plantdreamer.pipeline.model.density_ops import DensifyStats, densify_and_prune
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.model.init import SURFACE_THICKNESS, init_gaussians, initial_colors
from plantdreamer.pipeline.model.sampler import CameraSampler
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.settings.train_config import LearningRates
from plantdreamer.pipeline.state.checkpoint import _umask, load_checkpoint, save_checkpoint


def test_config_round_trips_through_json_dict():
    cfg = GenerateConfig.of(species="mint", seed=4, lr_means=1e-4)
    back = GenerateConfig.from_dict(cfg.to_dict())
    assert back == cfg
    with pytest.raises(InputError, match="unknown setting 'stepz'; did you mean 'steps'"):
        GenerateConfig.from_dict({**cfg.to_dict(), "stepz": 3})
    sectioned = dataclasses.asdict(cfg)  # the saved form up to 689da5e
    assert GenerateConfig.from_dict(sectioned) == cfg
    with pytest.raises(InputError, match="unknown config keys: stepz"):
        GenerateConfig.from_dict({**sectioned, "stepz": 3})


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"species": "bean", "color_init": "red"}, {"species": "bean", "sh_degree": 4}],
)
def test_config_rejects_bad_inputs(kwargs):
    with pytest.raises(InputError):
        GenerateConfig.of(**kwargs).validate()


def test_culling_removes_exactly_the_planted_giants(random_gaussians):
    g = random_gaussians(400, log_scale=-3.0)
    planted = [7, 123, 399]
    g.log_scales[planted] = 0.5
    mask, stats = large_gaussian_mask(torch.from_numpy(g.log_scales), 3.0)
    assert torch.nonzero(mask).flatten().tolist() == planted
    # The threshold is the paper's: mean + 3 std of V = ||exp(s)||.
    v = np.linalg.norm(np.exp(g.log_scales.astype(np.float64)), axis=1)
    assert stats["threshold"] == pytest.approx(v.mean() + 3 * v.std(ddof=1))


def test_checkpoint_is_atomic_and_corruption_is_reported(tmp_path):
    save_checkpoint(tmp_path, {"step": 3, "x": torch.arange(4)})
    assert load_checkpoint(tmp_path)["step"] == 3
    assert [p.name for p in tmp_path.iterdir()] == ["checkpoint.pt"]  # no temp file left
    # Readable like any other file the user creates (mkstemp alone would make it 0600).
    expected = 0o666 & ~_umask()
    assert (tmp_path / "checkpoint.pt").stat().st_mode & 0o777 == expected
    (tmp_path / "checkpoint.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="cannot read"):
        load_checkpoint(tmp_path)
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "nope")


def test_checkpoint_of_an_older_format_is_refused_with_the_way_out(tmp_path):
    # Format 2 runs began from spheres; resuming one under the disc default would mislabel it.
    torch.save({"format": 2, "step": 3}, tmp_path / "checkpoint.pt")
    with pytest.raises(
        CheckpointError, match=r"format 2; .* resumes formats 3 to 5 only .*--overwrite"
    ):
        load_checkpoint(tmp_path)


def test_remove_and_append_keep_adam_state_aligned(random_gaussians):
    model = GaussianModel(random_gaussians(10, log_scale=-3.0), LearningRates())
    for p in model.params.values():
        p.grad = torch.ones_like(p)
    model.optimizer.step()
    before = model.optimizer.state[model.params["means"]]["exp_avg"].clone()
    mask = torch.zeros(10, dtype=torch.bool)
    mask[[2, 5]] = True
    model.remove(mask)
    assert len(model) == 8
    after = model.optimizer.state[model.params["means"]]["exp_avg"]
    torch.testing.assert_close(after, before[~mask])
    new = {k: v.detach()[:3].clone() for k, v in model.params.items()}
    model.append(new)
    assert len(model) == 11
    state = model.optimizer.state[model.params["means"]]
    assert not state["exp_avg"][8:].any() and state["exp_avg"].shape == (11, 3)
    # The optimiser really optimises the new tensors.
    for p in model.params.values():
        p.grad = torch.ones_like(p)
    old = model.params["means"].detach().clone()
    model.optimizer.step()
    assert not torch.equal(old, model.params["means"].detach())


def test_densify_clones_small_splits_large_prunes_transparent(random_gaussians):
    g = random_gaussians(6, log_scale=-5.0)
    g.log_scales[1] = np.log(0.2)  # large: split
    g.opacity_logits[5] = -10.0  # transparent: pruned
    model = GaussianModel(g, LearningRates())
    stats = DensifyStats.zeros(6)
    grad = torch.zeros(1, 6, 2)
    grad[0, [0, 1], 0] = 1.0  # big 2D-mean gradient for Gaussians 0 and 1
    stats.update(grad, torch.ones(1, 6, dtype=torch.int32), 64, 64)
    counts = densify_and_prune(
        model, stats, 2e-4, 0.04, 0.05, 1000, torch.Generator().manual_seed(0)
    )
    assert counts == {"cloned": 1, "split": 1, "pruned": 1, "capped": 0, "too_big": 0}
    # 6 + 1 clone + 2 split samples - 1 split original - 1 pruned
    assert len(model) == 7
    scales = torch.exp(model.params["log_scales"]).amax(dim=1)
    assert torch.isclose(scales, torch.tensor(0.2 / 1.6)).sum() == 2


def test_densify_respects_the_cap(random_gaussians):
    model = GaussianModel(random_gaussians(6, log_scale=-5.0), LearningRates())
    stats = DensifyStats.zeros(6)
    stats.update(torch.ones(1, 6, 2), torch.ones(1, 6, dtype=torch.int32), 64, 64)
    densify_and_prune(model, stats, 2e-4, 0.04, 0.0, 8, torch.Generator().manual_seed(0))
    assert len(model) == 8


def test_colour_inits():
    rng = np.random.default_rng(0)
    rgb = np.full((4, 3), 0.3, np.float32)
    assert (initial_colors(rgb, 4, "original", rng) == 0.3).all()
    assert (initial_colors(rgb, 4, "black", rng) == 0).all()
    assert (initial_colors(rgb, 4, "white", rng) == 1).all()
    noise = initial_colors(rgb, 4, "noise", rng)
    assert noise.shape == (4, 3) and 0 <= noise.min() and noise.max() <= 1 and noise.std() > 0
    with pytest.raises(InputError):
        initial_colors(rgb, 4, "purple", rng)


def _rotation(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_surface_init_lays_flat_discs_in_the_surface_and_stops_at_its_edge():
    rng = np.random.default_rng(4)
    n = 400
    points = rng.random((n, 3)).astype(np.float32)
    normals = rng.normal(size=(n, 3))
    normals[:3] = [[0, 0, 1], [0, 0, -1], [0, 0, 0]]  # along z, opposite z, unusable
    edge = np.full(n, np.inf, np.float32)
    edge[5] = 0.01
    sphere = init_gaussians(points, None, 0.5)
    g = init_gaussians(points, None, 0.5, normals=normals, boundary_distance=edge)
    for i in range(3, n):  # the disc's thin (local z) axis is the normal
        unit = normals[i] / np.linalg.norm(normals[i])
        np.testing.assert_allclose(_rotation(g.quats[i].astype(np.float64))[:, 2], unit, atol=1e-6)
    np.testing.assert_allclose(_rotation(g.quats[1].astype(np.float64))[:, 2], [0, 0, -1])
    np.testing.assert_array_equal(g.quats[[0, 2]], [[1, 0, 0, 0], [1, 0, 0, 0]])
    # In the surface: the sphere's scale (capped near the edge); along the normal: thin.
    keep = np.arange(n) != 5
    np.testing.assert_array_equal(g.log_scales[keep, :2], sphere.log_scales[keep, :2])
    flat = keep & (np.arange(n) != 2)
    thin = sphere.log_scales[flat, 2] + np.log(SURFACE_THICKNESS)
    np.testing.assert_allclose(g.log_scales[flat, 2], thin, atol=1e-6)
    assert g.log_scales[2, 2] == sphere.log_scales[2, 2]  # no usable normal: a sphere
    np.testing.assert_allclose(np.exp(g.log_scales[5, :2]), [0.005, 0.005], rtol=1e-6)


def test_camera_sampler_is_seeded_and_resumable():
    from plantdreamer.pipeline.settings.train_config import CameraRanges

    a = CameraSampler(CameraRanges(), 32, seed=1)
    first = [a.sample() for _ in range(3)]
    state = a.state()
    nxt = a.sample()
    b = CameraSampler(CameraRanges(), 32, seed=1)
    assert np.array_equal(b.sample().viewmat, first[0].viewmat)
    b.set_state(state)
    assert np.array_equal(b.sample().viewmat, nxt.viewmat)
    for cam in first:
        assert 3.0 <= cam.distance <= 6.0 and -10.0 <= cam.elevation_deg <= 80.0


def test_native_culling_names_a_wrong_array():
    from plantdreamer import _core

    with pytest.raises(InputError, match="log_scales must be a float32 array"):
        _core.large_gaussian_mask(np.zeros((4, 3)), 3.0)  # float64
    with pytest.raises(InputError, match=r"log_scales must have shape \[N, 3\]"):
        _core.large_gaussian_mask(np.zeros((4, 2), np.float32), 3.0)


def test_plants_resume_together_from_their_last_common_step():
    from plantdreamer.pipeline.state.checkpoint import common_starts

    cur, prev = "checkpoint.pt", "checkpoint.prev.pt"
    # Killed between two plants' writes at step 8: all go back to 4 together.
    lockstep = {"a": {8: cur, 4: prev}, "b": {4: cur}, "c": {4: cur}}
    assert common_starts(lockstep) == [(4, ["a", "b", "c"])]
    # Killed while the previous files were going: all hold 8.
    assert common_starts({"a": {8: cur}, "b": {8: cur, 4: prev}}) == [(8, ["a", "b"])]
    # Trained apart (one started afresh beside resumed ones): each at its own step.
    apart = {"a": {6: cur}, "b": {}, "c": {2: cur}, "d": {6: cur}}
    assert common_starts(apart) == [(None, ["b"]), (2, ["c"]), (6, ["a", "d"])]
