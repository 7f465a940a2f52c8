"""Species LoRA training with tiny random models on the CPU (issue 10's acceptance)."""

import json
import math

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from PIL import Image, ImageDraw
from safetensors.torch import load_file

from plantdreamer.cli import main
from plantdreamer.errors import CheckpointError, InputError, ModelNotFoundError
from plantdreamer.guidance.lora_weights import load_lora, recorded_template
from plantdreamer.guidance.tiny import save_tiny_models, tiny_models, tiny_pipeline
from plantdreamer.lora.dataset import check_caption_template, load_examples
from plantdreamer.lora.train import LoraTrainConfig, train_lora

RES = 64


def make_images(folder, n=6, seed=0):
    """Synthetic 'plant photos': green ellipses on an off-white background, in mixed sizes
    and image modes (RGB, RGBA, greyscale, palette), one with its own caption."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    sizes = [(72, 80), (64, 64), (96, 70), (80, 120), (64, 90), (100, 64)]
    modes = ["RGB", "RGBA", "L", "P", "RGB", "RGB"]
    for i in range(n):
        w, h = sizes[i % len(sizes)]
        im = Image.new("RGB", (w, h), (245, 245, 240))
        draw = ImageDraw.Draw(im)
        for _ in range(5):
            cx, cy = rng.uniform(0.2, 0.8) * w, rng.uniform(0.2, 0.8) * h
            rx, ry = rng.uniform(5, 15), rng.uniform(3, 10)
            draw.ellipse(
                [cx - rx, cy - ry, cx + rx, cy + ry], fill=(30, int(rng.uniform(90, 180)), 40)
            )
        mode = modes[i % len(modes)]
        im = im.convert(mode) if mode != "RGB" else im
        im.save(folder / f"plant_{i:02d}.png")
    (folder / "plant_00.txt").write_text("a photo of a bean plant with five leaves\n")
    return folder


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    return make_images(tmp_path_factory.mktemp("photos"))


@pytest.fixture(scope="module")
def base_model(tmp_path_factory):
    base, _ = save_tiny_models(tmp_path_factory.mktemp("models"))
    return base


def config(images, out, **kw):
    kw.setdefault("resolution", RES)
    kw.setdefault("steps", 20)
    kw.setdefault("learning_rate", 1e-2)
    kw.setdefault("device", "cpu")
    return LoraTrainConfig(images_dir=str(images), out=str(out), **kw)


def unet_output(unet):
    g = torch.Generator().manual_seed(9)
    x, emb = torch.randn(1, 4, 8, 8, generator=g), torch.randn(1, 77, 32, generator=g)
    with torch.no_grad():
        return unet(x, torch.tensor([400]), emb).sample


def test_dataset_converts_modes_resizes_and_reads_captions(images):
    examples = load_examples(images, "bean", RES)
    assert len(examples) == 6
    assert {e.original_mode for e in examples} == {"RGB", "RGBA", "L", "P"}
    for e in examples:
        assert e.image.shape[0] == 3 and min(e.image.shape[1:]) == RES
        assert 0.0 <= float(e.image.min()) and float(e.image.max()) <= 1.0
    assert examples[0].caption == "a photo of a bean plant with five leaves"
    assert examples[1].caption == "a bean plant in a pot"  # the generation template


def test_short_run_lowers_the_loss_and_writes_a_loadable_file(images, tmp_path):
    result = train_lora(config(images, tmp_path / "lora"), components=tiny_models())
    assert len(result.losses) == 20 and all(np.isfinite(result.losses))
    assert result.eval_loss_after < result.eval_loss_before
    assert result.weights.name == "pytorch_lora_weights.safetensors"
    keys = list(load_file(result.weights))
    assert keys and all(k.startswith("unet.") and ".lora." in k for k in keys)
    assert {k.split(".lora.")[0].rsplit(".", 1)[-1] for k in keys} >= {"to_q", "to_k", "to_v"}
    assert any(".to_out.0.lora.down.weight" in k for k in keys)
    down = next(v for k, v in load_file(result.weights).items() if k.endswith("down.weight"))
    assert down.shape[0] == 4  # rank 4
    meta = json.loads(result.metadata.read_text())
    assert meta["config"]["rank"] == 4 and meta["steps_done"] == 20
    # Saved under the names typed for them (--lr, --prompt-template), read back as generate's.
    assert meta["config"]["lr"] == 1e-2 and "learning_rate" not in meta["config"]
    assert recorded_template(result.weights) == meta["config"]["prompt-template"]
    assert meta["eval_loss_after"] < meta["eval_loss_before"]

    # A fresh tiny pipeline: our loader and diffusers' load_lora_weights agree, and differ
    # from the plain UNet.
    plain = unet_output(tiny_models().unet)
    ours = tiny_models()
    load_lora(ours.unet, result.weights)
    pipe = tiny_pipeline()
    pipe.load_lora_weights(str(result.weights.parent), weight_name=result.weights.name)
    a, b = unet_output(ours.unet), unet_output(pipe.unet)
    assert (a - plain).abs().max() > 1e-4
    torch.testing.assert_close(a, b)


def test_authors_key_layout_loads_into_a_diffusers_pipeline(tmp_path):
    """A file like the authors' (diffusers keys, rank 4, UNet attention only)."""
    g = torch.Generator().manual_seed(0)
    sd = {}
    for name, module in tiny_models().unet.named_modules():
        if name.endswith(("to_q", "to_k", "to_v", "to_out.0")) and isinstance(
            module, torch.nn.Linear
        ):
            sd[f"unet.{name}.lora.down.weight"] = (
                torch.randn(4, module.in_features, generator=g) * 0.1
            )
            sd[f"unet.{name}.lora.up.weight"] = (
                torch.randn(module.out_features, 4, generator=g) * 0.1
            )
    from safetensors.torch import save_file

    (tmp_path / "bean").mkdir()
    save_file(sd, tmp_path / "bean" / "pytorch_lora_weights.safetensors")
    pipe = tiny_pipeline()
    plain = unet_output(pipe.unet)
    # Exactly the authors' loading call.
    pipe.load_lora_weights(str(tmp_path / "bean"), weight_name="pytorch_lora_weights.safetensors")
    ours = tiny_models()
    load_lora(ours.unet, tmp_path / "bean")
    assert (unet_output(pipe.unet) - plain).abs().max() > 1e-3
    torch.testing.assert_close(unet_output(pipe.unet), unet_output(ours.unet))


def test_resume_continues_the_same_run(images, tmp_path):
    straight = train_lora(
        config(images, tmp_path / "a", steps=6, checkpoint_every=3, grad_accum=2),
        components=tiny_models(),
    )
    first = train_lora(
        config(images, tmp_path / "b", steps=3, checkpoint_every=3, grad_accum=2),
        components=tiny_models(),
    )
    assert len(first.losses) == 3
    resumed = train_lora(
        config(images, tmp_path / "b", steps=6, checkpoint_every=3, grad_accum=2, resume=True),
        components=tiny_models(),
    )
    assert resumed.resumed_from == 3
    assert resumed.losses == straight.losses
    a, b = load_file(straight.weights), load_file(resumed.weights)
    assert a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), key


def test_resume_with_other_settings_is_refused(images, tmp_path):
    train_lora(config(images, tmp_path, steps=2, checkpoint_every=1), components=tiny_models())
    with pytest.raises(CheckpointError, match="--resume"):
        train_lora(config(images, tmp_path, steps=2), components=tiny_models())
    with pytest.raises(CheckpointError, match="rank"):
        train_lora(config(images, tmp_path, steps=4, rank=8, resume=True), components=tiny_models())


def test_records_of_earlier_versions_read_under_the_typed_names(images, tmp_path):
    """lora.json and checkpoint fingerprints saved under the field names still read: an old
    checkpoint of the same settings resumes, and its template reaches generate."""
    from plantdreamer.lora.checkpoint import check_fingerprint
    from plantdreamer.lora.config import LoraTrainConfig as Config

    cfg = config(images, tmp_path, learning_rate=3e-4, caption_template="{species} leaves")
    new = cfg.fingerprint(load_examples(images, "bean", RES))
    fields = {
        "learning_rate": "lr",
        "caption_template": "prompt-template",
        "base_model": "base-model",
        "batch_size": "batch-size",
        "grad_accum": "grad-accum",
    }
    old = {next((f for f, n in fields.items() if n == k), k): v for k, v in new.items()}
    assert "learning_rate" in old and Config.typed_names(old) == new
    check_fingerprint(tmp_path / "ckpt", Config.typed_names(old), new)  # the same run
    changed = config(images, tmp_path, learning_rate=1e-3, caption_template="{species} leaves")
    with pytest.raises(CheckpointError, match=r"lr: checkpoint 0\.0003, now 0\.001"):
        check_fingerprint(
            tmp_path / "ckpt",
            Config.typed_names(old),
            changed.fingerprint(load_examples(images, "bean", RES)),
        )
    (tmp_path / "lora.json").write_text(json.dumps({"config": {"caption_template": "a {species}"}}))
    assert recorded_template(tmp_path) == "a {species}"


def test_bad_image_folders_are_clear_errors(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no images"):
        load_examples(empty, "bean", RES)
    with pytest.raises(InputError, match="does not exist"):
        load_examples(tmp_path / "missing", "bean", RES)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "a.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    with pytest.raises(InputError, match=r"cannot read image .*a\.png"):
        load_examples(broken, "bean", RES)
    with pytest.raises(InputError, match="species"):
        load_examples(broken, "bean", RES, template="a photo")


def test_missing_base_model_is_a_clear_error(images, tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "cache"))
    with pytest.raises(ModelNotFoundError, match="--base-model"):
        train_lora(config(images, tmp_path / "o", base_model="nobody/no-such-model"))


def test_cli_trains_from_a_local_model_folder(images, base_model, tmp_path):
    out = tmp_path / "lora" / "bean"
    result = CliRunner().invoke(
        main,
        [
            "lora",
            "train",
            str(images),
            "--base-model",
            str(base_model),
            "--steps",
            "3",
            "--resolution",
            str(RES),
            "--out",
            str(out),
            "--device",
            "cpu",
            "--seed",
            "1",
        ],
    )
    assert result.exit_code == 0, result.output
    assert (out / "pytorch_lora_weights.safetensors").is_file()
    assert (out / "lora.json").is_file()
    assert "held-out denoising loss" in result.output


def test_cli_bad_folder_is_one_line_error(tmp_path):
    result = CliRunner().invoke(main, ["lora", "train", str(tmp_path / "nothing")])
    assert result.exit_code == 1
    assert result.output.strip().startswith("error:") and "does not exist" in result.output
    assert "Traceback" not in result.output


def test_validate_renders_sample_images(images, tmp_path):
    result = train_lora(
        config(images, tmp_path, steps=1, validate=2, validation_steps=2), components=tiny_models()
    )
    assert [p.name for p in result.validation_images] == ["sample-00.png", "sample-01.png"]
    with Image.open(result.validation_images[0]) as im:
        assert im.size == (RES, RES) and im.mode == "RGB"


def test_mixed_precision_without_a_gpu_is_refused(images, tmp_path):
    if torch.cuda.is_available():
        pytest.skip("a GPU is present")
    with pytest.raises(InputError, match="CUDA"):
        train_lora(config(images, tmp_path, mixed_precision=True), components=tiny_models())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("mixed_precision", [False, True])
def test_training_on_cuda_gives_finite_losses_and_weights(images, tmp_path, mixed_precision):
    # pragma: no cover - no GPU on CI
    result = train_lora(
        config(images, tmp_path, device="cuda", steps=6, mixed_precision=mixed_precision),
        components=tiny_models(),
    )
    assert len(result.losses) == 6 and all(math.isfinite(v) for v in result.losses)
    assert result.weights.is_file() and result.weights.stat().st_size > 0


def test_photos_captions_and_templates_that_cannot_train_are_clear_errors(tmp_path, monkeypatch):
    strip = tmp_path / "strip"
    strip.mkdir()
    Image.new("RGB", (20000, 1), (200, 200, 200)).save(strip / "a.png")  # 143 bytes
    with pytest.raises(InputError, match=r"would become 1280000 x 64.*crop it"):
        load_examples(strip, "bean", RES)
    big = tmp_path / "big"
    big.mkdir()
    Image.new("RGB", (64, 64)).save(big / "a.png")
    (big / "a.txt").write_bytes("une fève\n".encode("latin-1"))
    with pytest.raises(InputError, match=r"a\.txt' is not UTF-8"):
        load_examples(big, "bean", RES)
    (big / "a.txt").unlink()
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # Pillow's bomb limit, made tiny
    with pytest.raises(InputError, match=r"cannot read image .*a\.png.*decompression bomb"):
        load_examples(big, "bean", RES)
    monkeypatch.setattr("plantdreamer.lora.dataset.MAX_PHOTO_PIXELS", 4000)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", None)
    with pytest.raises(InputError, match="64 x 64 pixels, over the limit of 4,000"):
        load_examples(big, "bean", RES)
    for template in ("a {species} {pot}", "a {species} {}", "a {species"):
        with pytest.raises(InputError, match="caption template"):
            load_examples(big, "bean", RES, template=template)
    check_caption_template("{{a}} {species}")  # braces written double are text


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--alpha", "0"], "alpha=0"),
        (["--caption-template", "a {species} in {place}"], "{place}"),
        (["--caption-template", "a {species:d} plant"], "cannot format a species name"),
        (["--caption-template", "a {species!z} plant"], "cannot format a species name"),
        (["--caption-template", "a {species:d} plant", "--dry-run"], "cannot format"),
    ],
)
def test_cli_refuses_settings_that_cannot_train_before_any_model(tmp_path, args, message):
    folder = make_images(tmp_path / "photos", n=1)
    out = tmp_path / "o"
    result = CliRunner().invoke(main, ["lora", "train", str(folder), "--out", str(out), *args])
    assert result.exit_code == 1 and message in result.output, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in result.output
    assert not out.exists()


def test_dry_run_previews_every_size_and_refuses_a_strip_before_any_model(images, tmp_path):
    out = tmp_path / "o"
    result = CliRunner().invoke(
        main, ["lora", "train", str(images), "--resolution", "64", "--out", str(out), "--dry-run"]
    )
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert len(lines) == 6 and "plant_02.png: 96 x 70 -> 88 x 64" in lines
    assert not out.exists()
    Image.new("RGB", (20000, 1)).save(tmp_path / "strip.png")
    for dry_run in (["--dry-run"], []):
        result = CliRunner().invoke(
            main, ["lora", "train", str(tmp_path), "--out", str(out), *dry_run]
        )
        assert result.exit_code == 1 and "would become 10240000 x 512" in result.output
        assert len([x for x in result.output.splitlines() if x.startswith("error:")]) == 1
        assert not out.exists()
