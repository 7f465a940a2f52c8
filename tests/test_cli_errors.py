"""Bad input to any subcommand: exit 1, exactly one ``error:`` line, no traceback.

Each case is what a hostile user would try at that entry point: huge seeds, NaN and
out-of-range numbers, unusable devices, malformed datasets and checkpoints, folders that
hold another run. ``internal error`` (the CLI's catch-all for bugs) must not appear: every
case is an expected failure with its own message.
"""

import json
import pickle

import numpy as np
import pytest
import torch
from PIL import Image

from cli_run import run
from plantdreamer.cloud import PointCloud
from plantdreamer.io import write_ply, write_splat_ply
from plantdreamer.pipeline.model.init import init_gaussians

GEN = ["generate", "--species", "bean", "--guidance", "none", "--steps", "0", "--points", "500",
       "--resolution", "32", "--eval-views", "1"]  # fmt: skip


def assert_one_error(result, message):
    lines = result.output.splitlines()
    errors = [line for line in lines if line.startswith("error:")]
    assert result.exit_code == 1, result.output
    assert len(errors) == 1, result.output
    assert "Traceback" not in result.output and "internal error" not in result.output
    assert message in errors[0], result.output


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A small splat PLY, a point cloud, one image and dataset folders to break."""
    d = tmp_path_factory.mktemp("inputs")
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(400, 3)).astype(np.float32)
    write_splat_ply(d / "model.ply", init_gaussians(pts, None, 0.5))
    write_ply(d / "cloud.ply", PointCloud(pts, colors=rng.random((400, 3), dtype=np.float32)))
    Image.new("RGB", (16, 12)).save(d / "a.png")
    return d


def transforms(folder, frame_extra=None, top=None, raw=None):
    folder.mkdir(parents=True, exist_ok=True)
    if not (folder / "a.png").exists():
        Image.new("RGB", (16, 12)).save(folder / "a.png")
    if raw is not None:
        (folder / "transforms.json").write_bytes(raw)
        return folder
    frame = {"file_path": "a.png", "transform_matrix": np.eye(4).tolist(), "fl_x": 20.0}
    frame.update(frame_extra or {})
    meta = {"frames": [frame], **(top or {})}
    (folder / "transforms.json").write_text(json.dumps(meta))
    return folder


EYE = np.eye(4).tolist()
BAD_TRANSFORMS = {
    "string focal": dict(frame_extra={"fl_x": "twenty"}),
    "angle zero": dict(
        raw=json.dumps(
            {"camera_angle_x": 0, "frames": [{"file_path": "a.png", "transform_matrix": EYE}]}
        ).encode()
    ),
    "matrix of strings": dict(frame_extra={"transform_matrix": [["a"] * 4] * 4}),
    "matrix wrong shape": dict(frame_extra={"transform_matrix": [1, 2, 3]}),
    "non-utf8": dict(raw=b'{"frames": [{"file_path": "\xff\xfe"}]}'),
    "huge claimed size": dict(frame_extra={"file_path": "missing.png", "w": 30000, "h": 30000}),
    "string size": dict(frame_extra={"w": "wide"}),
}


@pytest.mark.parametrize("case", sorted(BAD_TRANSFORMS))
def test_render_with_malformed_transforms(files, tmp_path, case):
    folder = transforms(tmp_path / "ds", **BAD_TRANSFORMS[case])
    result = run("render", files / "model.ply", "--out", tmp_path / "r", "--transforms",
                 folder / "transforms.json")  # fmt: skip
    assert_one_error(result, "")


@pytest.mark.parametrize("case", ["string focal", "matrix of strings", "non-utf8", "string size"])
def test_eval_with_malformed_transforms(files, tmp_path, case):
    folder = transforms(tmp_path / "ds", **BAD_TRANSFORMS[case])
    result = run("eval", files / "model.ply", "--dataset", folder, "--out", tmp_path / "r.md")
    assert_one_error(result, "transforms.json")


COLMAP_CAMERAS = {
    "string width": "1 PINHOLE wide 12 20 20 8 6\n",
    "zero focal": "1 PINHOLE 16 12 0 20 8 6\n",
    "nan focal": "1 PINHOLE 16 12 nan 20 8 6\n",
    "huge image": "1 PINHOLE 30000 30000 20 20 8 6\n",
    "non-utf8": "1 PINHOLE 16 12 20 20 8 6 \udcff\n",
}


@pytest.mark.parametrize("case", sorted(COLMAP_CAMERAS))
def test_eval_with_malformed_colmap(files, tmp_path, case):
    ds = tmp_path / "colmap"
    (ds / "images").mkdir(parents=True)
    Image.new("RGB", (16, 12)).save(ds / "images" / "a.png")
    (ds / "cameras.txt").write_bytes(COLMAP_CAMERAS[case].encode("utf-8", "surrogateescape"))
    (ds / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.png\n\n")
    result = run("eval", files / "model.ply", "--dataset", ds, "--out", tmp_path / "r.md")
    assert_one_error(result, "")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--seed", 2**70], "seed"),
        (["--seed", -1], "seed"),
        (["--guidance-scale", "nan"], "guidance-scale must be finite"),
        (["--guidance-scale", -5], "guidance scale"),
        (["--points", 10**11], "points"),
        (["--resolution", 100000], "resolution"),
        (["--background", "nan"], "background must be finite"),
        (["--background", 1.5], "background must be a grey level"),
        (["--growth", 0], "growth must be in (0, 1], got 0"),
        (["--growth", 1.5], "growth must be in (0, 1], got 1.5"),
        (["--growth", 0.5, "--growth-since", 0.5], "growth-since 0.5 must be an earlier stage"),
    ],
)
def test_generate_bad_numbers(tmp_path, args, message):
    result = run(*GEN, "--out", tmp_path / "o", *args)
    assert_one_error(result, message)
    assert not (tmp_path / "o" / "plant.ply").exists()


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("background", float("nan"), "background must be finite"),
        ("background", 1.5, "background must be a grey level"),
        ("guidance_scale", float("nan"), "guidance-scale must be finite"),
        ("points", 3.7, "points must be an integer"),
        ("sh_degree", 2.5, "sh-degree must be an integer"),
        ("resolution", 3.7, "resolution must be an integer"),
        ("seed", True, "seed must be an integer"),
        ("steps", "10", "steps must be an integer"),
    ],
)
def test_generate_config_refuses_garbage_values(field, value, message):
    from plantdreamer.errors import InputError
    from plantdreamer.pipeline import GenerateConfig

    with pytest.raises(InputError, match=message):
        GenerateConfig.of(species="bean", **{field: value}).validate()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--background", "nan"], "--background"),
        (["--background", -0.1], "--background"),
        (["--resolution", 100000], "--resolution"),
        (["--eval-views", 0], "--eval-views"),
        (["--views", 0], "--eval-views"),  # its earlier name, still accepted
    ],
)
def test_render_bad_numbers(files, tmp_path, args, message):
    assert_one_error(run("render", files / "model.ply", "--out", tmp_path / "r", *args), message)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["render", "{model}", "--out", "{d}/r", "--views", 3, "--eval-views", 4], "--views"),
        (["render", "{model}", "--out", "{d}/r", "--distance", 3, "--eval-distance", 4],
         "--distance"),
        (["prepare", "{cloud}", "-o", "{d}/p.ply", "--target", 300, "--points", 200], "--target"),
        (["prepare", "{cloud}", "-o", "{d}/p.ply", "--size", 2, "--scene-size", 3], "--size"),
        (["prepare", "{cloud}", "-o", "{d}/p.ply", "--output", "{d}/q.ply"], "--output"),
        (["lsystem", "bean", "-o", "{d}/p.ply", "--output", "{d}/q.ply"], "--output"),
        (["dataset", "--species", "bean", "--seeds", "0-3", "--count", 3, "--dry-run",
          "--out", "{d}/ds"], "--count / --seed-start"),
        (["ablate", "--pointcloud", "{cloud}", "--dataset", "{d}", "--colors", "noise",
          "--color-init", "black", "--out", "{d}/a"], "--colors"),
        (["lora", "train", "{d}", "--out", "{d}/l", "--caption-template", "a {species}",
          "--prompt-template", "the {species}"], "--caption-template"),
    ],
)  # fmt: skip
def test_an_earlier_option_name_beside_its_new_name_with_another_value_is_refused(
    files, tmp_path, args, message
):
    """Neither name silently wins: one error line naming both, before anything is written."""
    paths = {"{model}": files / "model.ply", "{cloud}": files / "cloud.ply", "{d}": tmp_path}
    for key, path in paths.items():
        args = [a.replace(key, str(path)) if isinstance(a, str) else a for a in args]
    result = run(*args)
    assert_one_error(result, message)
    assert "give --" in result.output
    assert list(tmp_path.iterdir()) == []


def test_an_earlier_option_name_with_the_same_value_is_the_same_request(files, tmp_path):
    out = tmp_path / "p.ply"
    result = run("prepare", files / "cloud.ply", "-o", out, "--target", 300, "--points", 300)
    assert result.exit_code == 0, result.output
    assert out.is_file()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--device", "banana"], "banana"),
        (["--seed", 2**70], "seed"),
        (["--resume"], "nothing to resume"),
    ],
)
def test_lora_train_bad_requests(files, tmp_path, args, message):
    result = run("lora", "train", files, "--out", tmp_path / "l", "--base-model",
                 tmp_path / "no-model", *args)  # fmt: skip
    assert_one_error(result, message)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_lora_train_cuda_without_cuda(files, tmp_path):
    result = run("lora", "train", files, "--out", tmp_path / "l", "--device", "cuda")
    assert_one_error(result, "CUDA")


def test_unreadable_input_is_one_line(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"\x00\xff not a ply")
    assert_one_error(run("prepare", bad, "-o", tmp_path / "o.ply"), "")
    assert_one_error(run("render", bad, "--out", tmp_path / "r"), "")


# --- checkpoints ----------------------------------------------------------------------------


def test_crafted_checkpoint_does_not_run_code(tmp_path):
    """A pickle whose loading would run code is refused (weights_only=True)."""
    marker = tmp_path / "pwned"

    class Exploit:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    out = tmp_path / "run"
    out.mkdir()
    with open(out / "checkpoint.pt", "wb") as f:
        pickle.dump({"format": 1, "x": Exploit()}, f)
    torch.save({"format": 1, "config": Exploit()}, out / "checkpoint.pt")
    result = run("generate", "--resume", out)
    assert_one_error(result, "checkpoint")
    assert not marker.exists()


@pytest.mark.parametrize(
    "damage",
    [
        lambda s: s.pop("model"),
        lambda s: s.pop("config"),
        lambda s: s.update(step="seven"),
        lambda s: s.update(initial={"means": torch.zeros(3)}),
        lambda s: s["config"].update(seed="zero"),
        lambda s: s.update(sampler=[1, 2]),
    ],
    ids=["no model", "no config", "string step", "bad initial", "string seed", "bad sampler"],
)
def test_malformed_checkpoint_is_one_line(interrupted_run, tmp_path, damage):
    import shutil

    out = tmp_path / "run"
    shutil.copytree(interrupted_run, out)
    state = torch.load(out / "checkpoint.pt", weights_only=True)
    damage(state)
    torch.save(state, out / "checkpoint.pt")
    assert_one_error(run("generate", "--resume", out, "--quiet"), "checkpoint")


@pytest.fixture(scope="module")
def interrupted_run(tmp_path_factory):
    """A run folder with a checkpoint at step 2 of 4 and no final outputs."""
    from plantdreamer.pipeline import GenerateConfig, generate_plants
    from plantdreamer.pipeline.state.checkpoint import CHECKPOINT_NAME

    out = tmp_path_factory.mktemp("interrupted") / "run"
    cfg = GenerateConfig.of(species="bean", guidance="none", steps=4, checkpoint_every=2,
                         points=500, resolution=32, eval_views=1, turntable_frames=1, seed=5)  # fmt: skip
    import os
    import signal

    from plantdreamer.pipeline import RunInterrupted

    def ctrl_c(step):  # Ctrl-C during step 1: the run stops at step 2 with a checkpoint
        if step == 1:
            os.kill(os.getpid(), signal.SIGINT)

    with pytest.raises(RunInterrupted):
        generate_plants([cfg], out, show_progress=False, on_step=ctrl_c)
    assert not (out / "run.json").exists() and (out / CHECKPOINT_NAME).is_file()
    return out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--seed", 6], "seed: checkpoint 5, given 6"),
        (["--species", "kale"], "species"),
        (["--growth", 0.5], "growth: checkpoint 1.0, given 0.5"),  # another stage
        (["--steps", 1], "below the checkpoint's step"),
        (["--out", "elsewhere"], "drop --out"),
    ],
)
def test_resume_refuses_contradicting_options(interrupted_run, args, message):
    result = run("generate", "--resume", interrupted_run, "--quiet", *args)
    if "--out" in args:  # a usage error: click's own format, exit 2
        assert result.exit_code == 2 and message in result.output
        return
    assert_one_error(result, message)


def test_resume_applies_more_steps(interrupted_run, tmp_path):
    import shutil

    out = tmp_path / "run"
    shutil.copytree(interrupted_run, out)
    result = run("generate", "--resume", out, "--quiet", "--steps", 6, "--seed", 5)
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "run.json").read_text())
    assert summary["config"]["steps"] == 6
    assert {"step": 2, "event": "steps changed", "from": 4, "to": 6} in summary["events"]


# --- output folders -------------------------------------------------------------------------


def test_generate_refuses_a_finished_run_folder_without_overwrite(tmp_path):
    out = tmp_path / "o"
    assert run(*GEN, "--out", out, "--quiet").exit_code == 0
    before = (out / "plant.ply").read_bytes()
    assert_one_error(run(*GEN, "--out", out, "--quiet", "--seed", 1), "--overwrite")
    assert (out / "plant.ply").read_bytes() == before
    again = run(*GEN, "--out", out, "--quiet", "--seed", 1, "--overwrite")
    assert again.exit_code == 0, again.output
    assert json.loads((out / "run.json").read_text())["config"]["seed"] == 1
    assert sorted(p.name for p in out.iterdir()) == [
        "coco.json", "counts.csv", "depth", "instances", "labels", "log.csv", "plant.ply",
        "points.ply", "progress", "progress.png", "renders", "run.json", "traits.json",
        "transforms.json", "turntable.gif", "yolo",
    ]  # fmt: skip


@pytest.mark.parametrize("command", ["generate", "render", "prepare", "eval"])
def test_a_second_run_on_locked_outputs_fails_clearly(files, tmp_path, command):
    from plantdreamer.output_folder import LOCK_NAME, claim_files, claim_folder

    out = tmp_path / "o"
    if command in ("generate", "render"):
        holder = claim_folder(out)
        args = [*GEN, "--out", out] if command == "generate" else ["render", files / "model.ply",
                                                                   "--out", out]  # fmt: skip
    elif command == "prepare":
        holder = claim_files([tmp_path / "p.ply", tmp_path / "p.transform.json"])
        args = ["prepare", files / "cloud.ply", "-o", tmp_path / "p.ply"]
    else:
        holder = claim_files([tmp_path / "r.md"])
        args = ["eval", files / "model.ply", "--dataset", transforms(tmp_path / "ds"),
                "--out", tmp_path / "r.md"]  # fmt: skip
    with holder:
        assert_one_error(run(*args), "in use by another plantdreamer run")
    assert not (out / LOCK_NAME).exists()


def test_concurrent_claims_never_report_a_false_unwritable_folder(tmp_path):
    """Many runs probing one folder at once: each gets the lock or 'in use', never
    'not writable' (the old probe created and deleted one fixed file name)."""
    import threading

    from plantdreamer.errors import InputError
    from plantdreamer.output_folder import claim_folder

    errors = []

    def claim(i):
        for _ in range(50):
            try:
                with claim_folder(tmp_path / "o", allow_existing=True):
                    pass
            except InputError as exc:
                assert "in use" in str(exc)
            except OSError as exc:
                errors.append(exc)

    threads = [threading.Thread(target=claim, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []


@pytest.mark.parametrize("command", ["prepare", "eval", "render"])
def test_existing_outputs_are_refused_without_overwrite(files, tmp_path, command):
    if command == "prepare":
        (tmp_path / "p.transform.json").write_text("{}")  # stale from an earlier --normalize
        args = ["prepare", files / "cloud.ply", "-o", tmp_path / "p.ply", "--points", 0,
                "--sor-neighbors", 0]  # fmt: skip
        stale = tmp_path / "p.transform.json"
    elif command == "eval":
        (tmp_path / "r.json").write_text("{}")
        args = ["eval", files / "model.ply", "--dataset", transforms(tmp_path / "ds"),
                "--out", tmp_path / "r.md", "--strip-views", 0]  # fmt: skip
        stale = tmp_path / "r.json"
    else:
        (tmp_path / "o").mkdir()
        (tmp_path / "o" / "view_099.png").write_bytes(b"old")
        args = ["render", files / "model.ply", "--out", tmp_path / "o", "--eval-views", 2,
                "--resolution", 16, "--turntable", "none"]  # fmt: skip
        stale = tmp_path / "o" / "view_099.png"
    assert_one_error(run(*args), "--overwrite")
    result = run(*args, "--overwrite")
    assert result.exit_code == 0, result.output
    if command == "eval":
        assert json.loads(stale.read_text())["mean"]
    else:
        assert not stale.exists()  # the stale companion is gone, not left beside new output


def fake_base(folder):
    """A folder laid out as a Stable Diffusion model, its weight files whole safetensors
    files (found by the checks, never loaded)."""
    from safetensors.numpy import save_file

    base = folder / "base"
    for part in ("unet", "vae", "text_encoder"):
        (base / part).mkdir(parents=True)
        (base / part / "config.json").write_text("{}")
        save_file({"weight": np.zeros(4, np.float32)}, str(base / part / "model.safetensors"))
    (base / "tokenizer").mkdir()
    (base / "tokenizer" / "vocab.json").write_text("{}")
    (base / "scheduler").mkdir()
    (base / "scheduler" / "scheduler_config.json").write_text("{}")
    return base


@pytest.mark.parametrize("command", ["ablate", "lora"])
def test_folders_of_earlier_runs_are_refused(files, tmp_path, command):
    out = tmp_path / "o"
    out.mkdir()
    (out / "lora.json" if command == "lora" else out / "ablation.md").write_text("earlier run")
    if command == "lora":  # a base model that is found: the folder is what is refused
        args = ["lora", "train", files, "--out", out, "--base-model", fake_base(tmp_path)]
    else:
        args = ["ablate", "--pointcloud", files / "cloud.ply", "--dataset",
                transforms(tmp_path / "ds"), "--guidance", "none", "--out", out]  # fmt: skip
    assert_one_error(run(*args), "not empty")
    assert (
        out / ("lora.json" if command == "lora" else "ablation.md")
    ).read_text() == "earlier run"
