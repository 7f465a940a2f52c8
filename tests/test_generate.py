"""End-to-end generation on the CPU: outputs, frames, determinism, resume, bad input."""

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.cloud import PointCloud
from plantdreamer.digests import file_digest
from plantdreamer.errors import ModelNotFoundError
from plantdreamer.pipeline import GenerateConfig, RunInterrupted, generate_plants
from plantdreamer.pipeline.export import STEP_PHASES
from plantdreamer.thread_policy import pinned_torch_threads

INRIA_SH0 = "x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3".split()
# By default plant.ply has SH degree 3 (zero-padded), the f_rest count INRIA's loader asserts.
INRIA_SH3 = [*INRIA_SH0[:9], *(f"f_rest_{i}" for i in range(45)), *INRIA_SH0[9:]]


SMALL = dict(points=1500, resolution=48, eval_views=4, turntable_frames=4, steps=0, guidance="none")


def small(**kw):
    return GenerateConfig.of(**{**SMALL, **kw})


def photometric_guidance(seed=0):
    """Fits renders to a fixed grey-green target: a cheap, deterministic training signal."""
    import torch

    from plantdreamer.guidance.base import PhotometricGuidance

    target = torch.full((1, 48, 48, 3), 0.4)
    target[..., 1] = 0.6
    return PhotometricGuidance(target)


def test_lsystem_plant_without_guidance_writes_every_output(tmp_path):
    plyfile = pytest.importorskip("plyfile")
    from plantdreamer.io import read_splat_ply

    result = generate_plants([small(species="bean", steps=700)], tmp_path, show_progress=False)[0]
    g = read_splat_ply(result.ply_path)
    assert len(g) == result.gaussians > 100
    props = [p.name for p in plyfile.PlyData.read(result.ply_path)["vertex"].properties]
    assert props == [*INRIA_SH3, "label", "instance"]  # INRIA order first, labels after
    assert sorted(p.name for p in (tmp_path / "renders").iterdir()) == [
        f"view_{i:03d}.png" for i in range(4)
    ]
    assert (tmp_path / "turntable.gif").stat().st_size > 0
    run = json.loads((tmp_path / "run.json").read_text())
    assert run["config"]["species"] == "bean" and run["config"]["seed"] == 0
    # Densify/prune rounds in (300, 900) every 100 steps; culling every 100 steps after 500.
    events = [(e["step"], e["event"]) for e in run["events"]]
    assert events == [(400, "densify"), (500, "densify"), (600, "densify"), (600, "cull")]
    assert (tmp_path / "log.csv").read_text().startswith("step,loss,gaussians")


def test_point_cloud_comes_back_in_its_original_frame(tmp_path):
    from plantdreamer.io import read_splat_ply, write_ply

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(3000, 3)).astype(np.float32) * [0.2, 0.3, 0.5] + [10.0, -20.0, 3.0]
    colors = rng.random((3000, 3), dtype=np.float32)
    write_ply(tmp_path / "in.ply", PointCloud(pts.astype(np.float32), colors=colors))
    cfg = small(pointcloud=str(tmp_path / "in.ply"), points=5000, sor_std=100.0)
    result = generate_plants([cfg], tmp_path / "out", show_progress=False)[0]
    g = read_splat_ply(result.ply_path)
    np.testing.assert_allclose(g.means.min(0), pts.min(0), atol=1e-4)
    np.testing.assert_allclose(g.means.max(0), pts.max(0), atol=1e-4)
    # Scales too are in input units: about the mean spacing of the input points.
    assert 0.005 < np.exp(g.log_scales).mean() < 0.2


TINY_SDS = dict(species="mint", resolution=64, seed=3)


def tiny_sds_guidance():
    from plantdreamer.guidance import StableDiffusionDepthGuidance, tiny_models

    return StableDiffusionDepthGuidance(components=tiny_models(), **TINY_SDS)


# torch's thread count as a machine (or ``taskset``) of n cores leaves it: the count torch
# takes from the cores the process may use.
cores = pinned_torch_threads


def run_stopped_by(sig, at_step: int, cfg: dict, out, guidance) -> int:
    """Runs `generate`, sending `sig` to this process after step `at_step`; returns the step
    the run stopped at (it must stop)."""

    def send(step):
        if step == at_step:
            os.kill(os.getpid(), sig)

    with pytest.raises(RunInterrupted) as stop:
        generate_plants([small(**cfg)], out, guidance=guidance, show_progress=False, on_step=send)
    return stop.value.step


def test_sigterm_writes_a_checkpoint_and_stops_like_ctrl_c(tmp_path):
    # A scheduler's SIGTERM before it kills the job: the run keeps its progress.
    cfg = dict(species="mint", steps=6, checkpoint_every=100, seed=3)
    previous = signal.getsignal(signal.SIGTERM)
    stopped_at = run_stopped_by(signal.SIGTERM, 2, cfg, tmp_path / "cut", photometric_guidance())
    assert stopped_at == 3
    assert signal.getsignal(signal.SIGTERM) is previous  # the handler is put back
    resumed = generate_plants(
        None, tmp_path / "cut", guidance=photometric_guidance(), resume=True, show_progress=False
    )[0]
    full = generate_plants(
        [small(**cfg)], tmp_path / "full", guidance=photometric_guidance(), show_progress=False
    )[0]
    assert resumed.ply_path.read_bytes() == full.ply_path.read_bytes()


@pytest.mark.parametrize("make_guidance", [photometric_guidance, tiny_sds_guidance])
@pytest.mark.slow
def test_optimisation_is_deterministic_and_resume_is_bit_identical(tmp_path, make_guidance):
    """The same bytes run after run and after a resume, on machines of one and two cores: the
    run's torch-threads, not the cores, sets torch's sums (SDS's networks round by it)."""
    cfg = dict(species="mint", steps=12, checkpoint_every=5, seed=3)
    with cores(2):
        full = generate_plants([small(**cfg)], tmp_path / "full", guidance=make_guidance(),
                        show_progress=False)[0]  # fmt: skip
    with cores(1):
        assert run_stopped_by(signal.SIGINT, 7, cfg, tmp_path / "cut", make_guidance()) == 8
    assert not (tmp_path / "cut" / "plant.ply").exists()
    with cores(2):
        resumed = generate_plants(
            None, tmp_path / "cut", guidance=make_guidance(), resume=True, show_progress=False
        )[0]
    assert full.ply_path.read_bytes() == resumed.ply_path.read_bytes()
    # The progress pictures of each checkpoint (5, 10, 12) and the loss plot: the same bytes.
    for name in (
        "progress.png",
        "loss.png",
        "progress/step_000005.png",
        "progress/step_000012.png",
    ):
        assert (tmp_path / "full" / name).read_bytes() == (tmp_path / "cut" / name).read_bytes()
    from PIL import Image

    with Image.open(tmp_path / "full" / "progress.png") as strip:
        assert strip.width == 3 * 128  # one picture per checkpoint, side by side
    masks = sorted((tmp_path / "full").glob("[lid]*/view_*.png"))  # labels, instances, depth
    assert len(masks) == 12
    for png in masks:  # the masks too are bit-identical
        assert (
            png.read_bytes() == (tmp_path / "cut" / png.relative_to(tmp_path / "full")).read_bytes()
        )
    with cores(1):
        again = generate_plants(
            [small(**cfg)], tmp_path / "again", guidance=make_guidance(), show_progress=False
        )[0]
    assert again.ply_path.read_bytes() == full.ply_path.read_bytes()
    for png in sorted((tmp_path / "full").glob("[lid]*/view_*.png")):  # labels, instances, depth
        assert (
            png.read_bytes()
            == (tmp_path / "again" / png.relative_to(tmp_path / "full")).read_bytes()
        )
    # And the optimisation really changed the model.
    from plantdreamer.io import read_splat_ply

    untrained = generate_plants(
        [small(species="mint", seed=3)], tmp_path / "untrained", show_progress=False
    )[0]
    assert not np.array_equal(
        read_splat_ply(untrained.ply_path).sh, read_splat_ply(full.ply_path).sh
    )


# Run in a process that may use one core: SDS on the tiny models, stopped after step 2.
CUT_ON_ONE_CORE = """
import json, os, signal, sys
import torch
from plantdreamer.guidance import StableDiffusionDepthGuidance, tiny_models
from plantdreamer.pipeline import GenerateConfig, RunInterrupted, generate_plants

settings, sds, out = json.loads(sys.argv[1]), json.loads(sys.argv[2]), sys.argv[3]
guidance = StableDiffusionDepthGuidance(components=tiny_models(), **sds)


def stop_after(step):
    if step == 2:
        os.kill(os.getpid(), signal.SIGINT)


try:
    generate_plants([GenerateConfig.of(**settings)], out, guidance=guidance, show_progress=False,
                    on_step=stop_after)
except RunInterrupted as stop:
    print(torch.get_num_threads(), stop.step)
"""


@pytest.mark.skipif(shutil.which("taskset") is None, reason="needs taskset (util-linux)")
@pytest.mark.slow
def test_sds_stopped_under_taskset_one_core_resumes_on_two_to_the_unbroken_run(tmp_path):
    """``generate`` started under ``taskset`` on one core, stopped, then resumed where torch
    would use two threads, writes the plant.ply of the unbroken two-core run."""
    cfg = {**SMALL, "species": "mint", "steps": 4, "checkpoint_every": 100, "seed": 3,
           "eval_views": 1, "turntable": "none"}  # fmt: skip
    core = str(min(os.sched_getaffinity(0)))
    cut = subprocess.run(
        ["taskset", "-c", core, sys.executable, "-c", CUT_ON_ONE_CORE, json.dumps(cfg),
         json.dumps(TINY_SDS), str(tmp_path / "cut")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert cut.stdout.split() == ["1", "3"], cut.stderr  # torch saw one core; stopped at 3
    with cores(2):
        resumed = generate_plants(None, tmp_path / "cut", guidance=tiny_sds_guidance(), resume=True,
                           show_progress=False)[0]  # fmt: skip
        full = generate_plants([GenerateConfig.of(**cfg)], tmp_path / "full",
                        guidance=tiny_sds_guidance(), show_progress=False)[0]  # fmt: skip
    assert resumed.ply_path.read_bytes() == full.ply_path.read_bytes()


@pytest.mark.parametrize("saved_on", ["recorded", "older checkpoint"])
def test_noise_drawn_on_cuda_does_not_resume_on_the_cpu(tmp_path, saved_on):
    """A run whose SDS noise came from a CUDA generator, resumed where the guidance draws on
    the CPU, stops with one line naming both devices, not torch's state error. Format-4
    checkpoints (the noise in the plant's checkpoint) from before the device was recorded
    are told by the state's size."""
    import torch

    from plantdreamer.errors import CheckpointError

    cfg = dict(species="mint", steps=6, checkpoint_every=100, seed=3)
    assert run_stopped_by(signal.SIGINT, 2, cfg, tmp_path / "cut", tiny_sds_guidance()) == 3
    noise_file = tmp_path / "cut" / "noise.pt"
    saved = torch.load(noise_file, weights_only=True)
    noise = saved["trainers"][0]["steps"]["3"]
    assert noise["guidance_device"] == "cpu"
    cuda_state = torch.zeros(16, dtype=torch.uint8)  # a Philox (CUDA) state's size
    if saved_on == "recorded":
        saved["trainers"][0]["steps"]["3"] = {"guidance": cuda_state, "guidance_device": "cuda"}
        torch.save(saved, noise_file)
    else:
        path = tmp_path / "cut" / "checkpoint.pt"
        torch.save(_as_format_4(torch.load(path, weights_only=True), {"guidance": cuda_state}),
                   path)  # fmt: skip
        noise_file.unlink()
    with pytest.raises(CheckpointError, match=r"drawn on cuda.*draws on cpu.*--device"):
        generate_plants(None, tmp_path / "cut", guidance=tiny_sds_guidance(), resume=True,
                        show_progress=False)  # fmt: skip


def test_a_format_4_checkpoint_resumes_with_the_noise_it_carries(tmp_path):
    """Checkpoints written before the group's noise was saved apart (format 4: a copy in
    every plant's checkpoint) resume to the unbroken run's plant."""
    import torch

    cfg = dict(species="mint", steps=6, checkpoint_every=100, seed=3, turntable="none")
    full = generate_plants([small(**cfg)], tmp_path / "full", guidance=tiny_sds_guidance(),
                           show_progress=False)[0]  # fmt: skip
    assert run_stopped_by(signal.SIGINT, 2, cfg, tmp_path / "cut", tiny_sds_guidance()) == 3
    noise_file = tmp_path / "cut" / "noise.pt"
    noise = torch.load(noise_file, weights_only=True)["trainers"][0]["steps"]["3"]
    path = tmp_path / "cut" / "checkpoint.pt"
    torch.save(_as_format_4(torch.load(path, weights_only=True), noise), path)
    noise_file.unlink()
    resumed = generate_plants(None, tmp_path / "cut", guidance=tiny_sds_guidance(), resume=True,
                              show_progress=False)[0]  # fmt: skip
    assert resumed.ply_path.read_bytes() == full.ply_path.read_bytes()


def _as_format_4(state, noise):
    """A checkpoint as format 4 wrote it: the guidance's noise state in it."""
    return {**state, "format": 4, **noise}


def _as_format_3(state):
    """A format-4 checkpoint written the way format 3 was: one flat config (``densify``,
    ``cull``, ``lr``, ``cameras`` nested once; ``n_points``, ``sds_resolution``) and density
    control's state under ``densify``."""
    config = dataclasses.asdict(GenerateConfig.from_dict(state["config"]))  # sectioned
    flat = {"preset": config.pop("preset"), "seed": config.pop("seed")}
    train = config.pop("train")
    density = config.pop("density")
    sds = config.pop("sds")
    sds["sds_resolution"] = sds.pop("resolution")
    source = config.pop("source")
    source["n_points"] = source.pop("points")
    flat.update(lr=train.pop("lr"), cameras=train.pop("cameras"), **train, **density)
    outputs = config.pop("outputs")
    del outputs["views"]  # no rigs, scenes or looks then
    for section in (sds, source, config.pop("init"), outputs):
        flat.update(section)
    assert not config
    old = {k: v for k, v in state.items() if k != "density"}
    return {**old, "format": 3, "config": flat, "densify": state["density"]}


def _with_sections(state):
    """A format-4 checkpoint as 689da5e wrote it: the config in sections
    (``{"source": {"points": ...}, "density": {"densify": {"every": ...}}}``)."""
    sections = dataclasses.asdict(GenerateConfig.from_dict(state["config"]))
    return {**state, "config": json.loads(json.dumps(sections))}


@pytest.mark.parametrize("old_form", [_as_format_3, _with_sections])
def test_an_earlier_checkpoint_resumes_to_the_same_plant(tmp_path, old_form):
    import torch

    cfg = dict(species="mint", steps=12, checkpoint_every=5, seed=3)
    full = generate_plants(
        [small(**cfg)], tmp_path / "full", guidance=photometric_guidance(), show_progress=False
    )[0]
    assert run_stopped_by(signal.SIGINT, 7, cfg, tmp_path / "cut", photometric_guidance()) == 8
    path = tmp_path / "cut" / "checkpoint.pt"
    state = torch.load(path, weights_only=True)
    assert state["config"]["checkpoint-every"] == 5  # saved by name
    torch.save(old_form(state), path)
    resumed = generate_plants(
        None, tmp_path / "cut", guidance=photometric_guidance(), resume=True, show_progress=False
    )[0]
    assert resumed.ply_path.read_bytes() == full.ply_path.read_bytes()


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
        generate_plants(
            [small(guidance="sds", species="bean", base_model=str(tmp_path / "no-model"))],
            tmp_path / "o",
            show_progress=False,
        )
    assert "no-model" in str(err.value)
    assert not (tmp_path / "o" / "plant.ply").exists()


def test_ablate_scores_each_colour_init(tmp_path):
    """Without optimisation, the original colours must beat black against images of the
    original cloud: the ablation measures what the colour init contributes."""
    import torch

    from plantdreamer.cameras import orbit_ring
    from plantdreamer.io import write_ply
    from plantdreamer.pipeline.model.gaussian_model import GaussianModel
    from plantdreamer.pipeline.model.init import init_gaussians

    rng = np.random.default_rng(1)
    pts = (rng.normal(size=(2000, 3)) * [0.3, 0.3, 1.0]).astype(np.float32)
    colors = np.clip(0.2 + 0.6 * rng.random((2000, 3)), 0, 1).astype(np.float32)
    write_ply(tmp_path / "in.ply", PointCloud(pts, colors=colors))
    # Ground truth: the initial model itself, at cameras in the input frame.
    g = init_gaussians(pts, colors, 0.1)
    model = GaussianModel(g)
    cams = orbit_ring(3, 8.0, 15.0, 50.0, 48, 48)
    frames = []
    import imageio.v3 as iio

    (tmp_path / "gt").mkdir()
    for i, cam in enumerate(cams):
        with torch.no_grad():
            rgb, alpha, _ = model.render([cam], 0.75)
        rgba = np.concatenate([rgb[0].numpy(), (alpha[0].numpy() > 0.5)], axis=-1)
        iio.imwrite(tmp_path / "gt" / f"{i}.png", (rgba * 255).round().astype(np.uint8))
        k = cam.K
        frames.append(
            {
                "file_path": f"gt/{i}.png",
                "transform_matrix": cam.to_opengl_c2w().tolist(),
                "fl_x": k[0, 0], "fl_y": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], "w": 48, "h": 48,
            }
        )  # fmt: skip
    (tmp_path / "transforms.json").write_text(json.dumps({"frames": frames}))
    result = CliRunner().invoke(
        main,
        [
            "ablate", "--pointcloud", str(tmp_path / "in.ply"), "--dataset", str(tmp_path),
            "--colors", "original,black", "--guidance", "none", "--steps", "0",
            "--resolution", "48", "--out", str(tmp_path / "abl"), "--quiet",
        ],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    table = (tmp_path / "abl" / "ablation.md").read_text()
    assert "| Original |" in table and "| Black |" in table
    scores = {
        c: json.loads((tmp_path / "abl" / c / "eval.json").read_text())["mean"]["masked_psnr"]
        for c in ("original", "black")
    }
    assert scores["original"] > scores["black"] + 3.0
    assert (tmp_path / "abl" / "ablation.png").stat().st_size > 0


def test_cli_sds_with_tiny_models_from_local_folders(tmp_path):
    """The real loading path (from_pretrained on hub-like folders) and a few SDS steps."""
    from plantdreamer.guidance import save_tiny_models

    base, controlnet = save_tiny_models(tmp_path / "models")
    out = tmp_path / "o"
    args = [
        "generate", "--species", "kale", "--seed", "2", "--guidance", "sds",
        "--base-model", str(base), "--controlnet", str(controlnet), "--steps", "3",
        "--points", "1500", "--resolution", "48", "--sds-resolution", "64",
        "--eval-views", "2", "--out", str(out), "--quiet",
    ]  # fmt: skip
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    rows = (out / "log.csv").read_text().strip().splitlines()
    assert len(rows) == 4  # header + 3 steps
    losses = [float(r.split(",")[1]) for r in rows[1:]]
    assert all(np.isfinite(losses)) and any(v > 0 for v in losses)
    run = json.loads((out / "run.json").read_text())
    assert set(STEP_PHASES) <= set(run["per_step_s"])
    # What the run read of its models, recorded as it finished: names, never paths.
    models = {m["role"]: m for m in run["models"]}
    unet = base / "unet" / "diffusion_pytorch_model.safetensors"
    files = {f["path"]: f["sha256"] for f in models["base model"]["files"]}
    assert files["unet/diffusion_pytorch_model.safetensors"] == file_digest(unet)
    assert models["depth ControlNet"]["name"] == controlnet.name
    assert str(tmp_path) not in json.dumps(run["models"])
    # The run ends saying what it wrote, how long it took and what to type next.
    assert f"wrote {out / 'plant.ply'} (" in result.output
    assert "progress.png, loss.png" in result.output and "done in " in result.output
    assert f"next: plantdreamer view {out / 'plant.ply'}" in result.output
    assert (out / "loss.png").read_bytes().startswith(b"\x89PNG")


def test_render_command_orbit_and_transforms(tmp_path):
    result = generate_plants([small(species="kale")], tmp_path / "g", show_progress=False)[0]
    runner = CliRunner()
    orbit = runner.invoke(
        main, ["render", str(result.ply_path), "--out", str(tmp_path / "r"), "--eval-views", "3",
               "--resolution", "32", "--turntable", "none"],
    )  # fmt: skip
    assert orbit.exit_code == 0, orbit.output
    assert len(list((tmp_path / "r").glob("view_*.png"))) == 3
    assert not list((tmp_path / "r").glob("turntable.*"))
    # transforms.json cameras in the model's own frame (kale is ~0.2 m tall, in metres).
    from plantdreamer.cameras import orbit as orbit_camera

    cam = orbit_camera(0.6, 20.0, 30.0, 50.0, 40, 30, target=(0.0, 0.0, 0.1))
    frame = {
        "file_path": "images/a.png", "transform_matrix": cam.to_opengl_c2w().tolist(),
        "fl_x": cam.K[0, 0], "fl_y": cam.K[1, 1], "cx": cam.K[0, 2], "cy": cam.K[1, 2],
        "w": 40, "h": 30,
    }  # fmt: skip
    (tmp_path / "transforms.json").write_text(json.dumps({"frames": [frame]}))
    views = runner.invoke(
        main,
        ["render", str(result.ply_path), "--out", str(tmp_path / "t"),
         "--transforms", str(tmp_path / "transforms.json")],
    )  # fmt: skip
    assert views.exit_code == 0, views.output
    import imageio.v3 as iio

    image = iio.imread(tmp_path / "t" / "a.png")
    assert image.shape == (30, 40, 3)
    # The plant is in view: some pixels differ from the grey background.
    assert (np.abs(image.astype(int) - 191).max(axis=-1) > 20).mean() > 0.05
