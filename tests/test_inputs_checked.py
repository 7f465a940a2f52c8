"""Every input a command reads is opened far enough to know it will load before anything is
deleted: a point cloud cut short (a whole header, its data cut), a LoRA that is not a
safetensors file, a base model whose weight file is cut short. ``--overwrite`` then deletes
nothing, and ``info --check`` calls such a file damaged and exits 1.
"""

from __future__ import annotations

import numpy as np
import pytest
from safetensors.numpy import save_file

from cli_run import one_error, run
from plantdreamer.cloud import PointCloud
from plantdreamer.errors import PlyError
from plantdreamer.io import check_ply_file, write_ply

TINY = ["--guidance", "none", "--points", "300", "--steps", "0", "--eval-views", "1",
        "--resolution", "16", "--turntable", "none", "--quiet"]  # fmt: skip


def snapshot(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}  # fmt: skip


def clouds(folder):
    """A whole point cloud and the same cut short by 100 bytes (its header whole)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    write_ply(folder / "cloud.ply", PointCloud(rng.normal(size=(400, 3)).astype(np.float32)))
    data = (folder / "cloud.ply").read_bytes()
    (folder / "cut.ply").write_bytes(data[:-100])
    return folder / "cloud.ply", folder / "cut.ply"


def weights(path, cut=0):
    path.parent.mkdir(parents=True, exist_ok=True)
    save_file({"w.lora.down.weight": np.zeros((64, 64), np.float32)}, str(path))
    if cut:
        path.write_bytes(path.read_bytes()[:-cut])
    return path


def model_folders(root, cut_unet=False):
    """A base model and ControlNet laid out as diffusers saves them (never loaded)."""
    base, control = root / "base", root / "controlnet"
    for part in ("unet", "vae", "text_encoder"):
        (base / part).mkdir(parents=True)
        (base / part / "config.json").write_text("{}")
        name = (
            "diffusion_pytorch_model.safetensors" if part != "text_encoder" else "model.safetensors"
        )
        weights(base / part / name, cut=1000 if cut_unet and part == "unet" else 0)
    (base / "tokenizer").mkdir()
    (base / "tokenizer" / "vocab.json").write_text("{}")
    (base / "scheduler").mkdir()
    (base / "scheduler" / "scheduler_config.json").write_text("{}")
    control.mkdir()
    (control / "config.json").write_text("{}")
    weights(control / "diffusion_pytorch_model.safetensors")
    return base, control


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished run's folder, as bytes to compare."""
    out = tmp_path_factory.mktemp("runs") / "run"
    assert run("generate", "--species", "bean", *TINY, "--out", out).exit_code == 0
    return out


def test_a_cloud_cut_short_is_refused_from_its_header(tmp_path):
    whole, cut = clouds(tmp_path)
    check_ply_file(whole)
    with pytest.raises(PlyError, match="truncated"):
        check_ply_file(cut, "point cloud")


def test_generate_overwrite_keeps_the_run_when_the_cloud_is_cut_short(finished, tmp_path):
    _, cut = clouds(tmp_path / "in")
    before = snapshot(finished)
    one_error(run("generate", "--pointcloud", cut, *TINY, "--out", finished, "--overwrite"),
              "truncated")  # fmt: skip
    assert snapshot(finished) == before


def test_prepare_overwrite_keeps_the_output_when_the_input_is_cut_short(tmp_path):
    _, cut = clouds(tmp_path)
    out = tmp_path / "prepared.ply"
    out.write_bytes(b"the earlier output")
    one_error(run("prepare", cut, "-o", out, "--points", 0, "--overwrite"), "truncated")
    assert out.read_bytes() == b"the earlier output"


@pytest.mark.parametrize("content", [b"not safetensors at all", None])
def test_generate_overwrite_keeps_the_run_when_the_lora_would_not_load(finished, tmp_path,
                                                                       content):  # fmt: skip
    lora = tmp_path / "bean.safetensors"
    if content is None:
        weights(lora, cut=100)  # a LoRA cut short
    else:
        lora.write_bytes(content)
    before = snapshot(finished)
    result = run("generate", "--species", "bean", *TINY, "--lora", lora, "--out", finished,
                 "--overwrite")  # fmt: skip
    one_error(result, "bean.safetensors")
    assert snapshot(finished) == before


def test_generate_overwrite_keeps_the_run_when_a_weight_file_is_cut_short(finished, tmp_path):
    base, control = model_folders(tmp_path, cut_unet=True)
    before = snapshot(finished)
    result = run("generate", "--species", "bean", *TINY, "--guidance", "sds", "--device", "cpu",
                 "--base-model", base, "--controlnet", control, "--out", finished,
                 "--overwrite")  # fmt: skip
    one_error(result, "unet/diffusion_pytorch_model.safetensors")
    assert snapshot(finished) == before


def test_lora_train_overwrite_keeps_the_lora_when_the_base_model_is_cut_short(tmp_path):
    from PIL import Image

    photos = tmp_path / "photos"
    photos.mkdir()
    Image.new("RGB", (64, 64), (30, 120, 40)).save(photos / "a.png")
    out = tmp_path / "lora"
    out.mkdir()
    (out / "lora.json").write_text("the earlier LoRA's record")
    base, _ = model_folders(tmp_path / "models", cut_unet=True)
    result = run("lora", "train", photos, "--out", out, "--base-model", base, "--resolution", 64,
                 "--device", "cpu", "--overwrite")  # fmt: skip
    one_error(result, "unet")
    assert (out / "lora.json").read_text() == "the earlier LoRA's record"


def test_info_check_calls_damaged_files_damaged(tmp_path):
    base, control = model_folders(tmp_path, cut_unet=True)
    lora = tmp_path / "bean.safetensors"
    lora.write_bytes(b"not safetensors at all")
    result = run("info", "--check", "--base-model", base, "--controlnet", control, "--lora", lora)
    rows = {line[: line.index("  ")].strip(): line[line.index("  ") :].strip()
            for line in result.output.splitlines()}  # fmt: skip
    assert rows["base model"].startswith("damaged:") and "unet/" in rows["base model"]
    assert rows["depth ControlNet"].startswith("present:")
    assert rows[f"LoRA {lora}"].startswith("damaged:")
    assert result.exit_code == 1
    whole, _ = model_folders(tmp_path / "whole")
    result = run("info", "--check", "--base-model", whole, "--controlnet", control)
    assert result.exit_code == 0, result.output
