"""End-to-end generation on the CPU: outputs, frames, determinism, resume, bad input."""

import json
import os
import signal

import numpy as np
import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.cloud import PointCloud
from plantdreamer.errors import ModelNotFoundError
from plantdreamer.pipeline import GenerateConfig, RunInterrupted, generate

INRIA_SH0 = "x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3".split()


def small(**kw):
    base = dict(n_points=1500, resolution=48, eval_views=4, turntable_frames=4, steps=0)
    base.update(kw)
    return GenerateConfig(**base)


def photometric_guidance(seed=0):
    """Fits renders to a fixed grey-green target: a cheap, deterministic training signal."""
    import torch
    from plantdreamer.guidance import PhotometricGuidance

    target = torch.full((1, 48, 48, 3), 0.4)
    target[..., 1] = 0.6
    return PhotometricGuidance(target)


def test_lsystem_plant_without_guidance_writes_every_output(tmp_path):
    plyfile = pytest.importorskip("plyfile")
    from plantdreamer.io import read_splat_ply

    result = generate(small(species="bean", steps=700), tmp_path, show_progress=False)
    g = read_splat_ply(result.ply_path)
    assert len(g) == result.gaussians > 100
    props = [p.name for p in plyfile.PlyData.read(result.ply_path)["vertex"].properties]
    assert props == INRIA_SH0
    assert sorted(p.name for p in (tmp_path / "renders").iterdir()) == [
        f"view_{i:03d}.png" for i in range(4)
    ]
    assert (tmp_path / "turntable.gif").stat().st_size > 0
    run = json.loads((tmp_path / "run.json").read_text())
    assert run["config"]["species"] == "bean" and run["seed"] == 0
    assert [e["event"] for e in run["events"]] == ["cull"] * 1  # step 600 only (> 500)
    assert (tmp_path / "log.csv").read_text().startswith("step,loss,gaussians")


def test_point_cloud_comes_back_in_its_original_frame(tmp_path):
    from plantdreamer.io import read_splat_ply, write_ply

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(3000, 3)).astype(np.float32) * [0.2, 0.3, 0.5] + [10.0, -20.0, 3.0]
    colors = rng.random((3000, 3), dtype=np.float32)
    write_ply(tmp_path / "in.ply", PointCloud(pts.astype(np.float32), colors=colors))
    cfg = small(pointcloud=str(tmp_path / "in.ply"), n_points=5000, sor_std=100.0)
    result = generate(cfg, tmp_path / "out", show_progress=False)
    g = read_splat_ply(result.ply_path)
    np.testing.assert_allclose(g.means.min(0), pts.min(0), atol=1e-4)
    np.testing.assert_allclose(g.means.max(0), pts.max(0), atol=1e-4)
    # Scales too are in input units: about the mean spacing of the input points.
    assert 0.005 < np.exp(g.log_scales).mean() < 0.2


def test_optimisation_is_deterministic_and_resume_is_bit_identical(tmp_path):
    cfg = dict(species="mint", steps=12, checkpoint_every=5, seed=3)
    full = generate(
        small(**cfg), tmp_path / "full", guidance=photometric_guidance(), show_progress=False
    )

    def interrupt_at_7(step):
        if step == 7:
            os.kill(os.getpid(), signal.SIGINT)

    with pytest.raises(RunInterrupted) as stop:
        generate(
            small(**cfg),
            tmp_path / "cut",
            guidance=photometric_guidance(),
            show_progress=False,
            on_step=interrupt_at_7,
        )
    assert stop.value.step == 8
    assert not (tmp_path / "cut" / "plant.ply").exists()
    resumed = generate(
        None, tmp_path / "cut", guidance=photometric_guidance(), resume=True, show_progress=False
    )
    assert full.ply_path.read_bytes() == resumed.ply_path.read_bytes()
    again = generate(
        small(**cfg), tmp_path / "again", guidance=photometric_guidance(), show_progress=False
    )
    assert again.ply_path.read_bytes() == full.ply_path.read_bytes()
    # And the optimisation really changed the model.
    from plantdreamer.io import read_splat_ply

    untrained = generate(small(species="mint", seed=3), tmp_path / "untrained", show_progress=False)
    assert not np.array_equal(
        read_splat_ply(untrained.ply_path).sh, read_splat_ply(full.ply_path).sh
    )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--species", "cactus"], "unknown species"),
        (["--pointcloud", "missing.ply"], "not found"),
    ],
)
def test_cli_bad_input_is_one_line(tmp_path, args, message):
    result = CliRunner().invoke(
        main, ["generate", *args, "--guidance", "none", "--out", str(tmp_path / "o")]
    )
    assert result.exit_code == 1
    assert message in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "o" / "plant.ply").exists()


def test_cli_unwritable_output(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    result = CliRunner().invoke(
        main, ["generate", "--species", "bean", "--guidance", "none", "--out", str(blocker / "o")]
    )
    assert result.exit_code == 1 and "not writable" in result.output


def test_missing_weights_name_what_to_download(tmp_path):
    with pytest.raises(ModelNotFoundError) as err:
        generate(
            small(species="bean", guidance="sds", base_model=str(tmp_path / "no-model")),
            tmp_path / "o",
            show_progress=False,
        )
    assert "no-model" in str(err.value)
    assert not (tmp_path / "o" / "plant.ply").exists()
