"""What a dataset's card is made from: the model files a run records (names and hashes,
never a local path) and the escaping of user-given names. The cards themselves, written
from generated plants, are tested in test_label_exports.py (its plant is made once)."""

from __future__ import annotations

import hashlib
import json
import shutil
from html.parser import HTMLParser

from plantdreamer.exports import LabelOptions
from plantdreamer.guidance.model_files import model_files_record

ALL_TRAIN = LabelOptions(ratios=(1.0, 0.0, 0.0), allow_empty_split=True)
SD = "stabilityai/stable-diffusion-2-1-base"


def dataset_of(bean, root, plants: dict[str, dict]) -> None:
    """A dataset folder of copies of ``bean``, each plant's run.json updated with its dict
    (``config``: settings over the recorded ones; any other key set as it is)."""
    for plant_id, changes in plants.items():
        folder = root / "plants" / plant_id
        shutil.copytree(bean, folder)
        record = json.loads((folder / "run.json").read_text())
        record["config"].update(changes.pop("config", {}))
        record.update(changes)
        if "models" not in changes:  # a record of a version before them
            record.pop("models", None)
        (folder / "run.json").write_text(json.dumps(record))


def local_models(tmp_path):
    """A base model folder, a ControlNet folder and a LoRA file on this machine."""
    base, control, lora = tmp_path / "models" / "sd", tmp_path / "models" / "cn", tmp_path / "lora"
    for part in ("unet", "vae", "text_encoder", "tokenizer", "scheduler"):
        (base / part).mkdir(parents=True)
        (base / part / "config.json").write_text(f'{{"part": "{part}"}}')
    (base / "unet" / "diffusion_pytorch_model.safetensors").write_bytes(b"unet weights")
    (base / "unet" / "diffusion_pytorch_model.fp16.safetensors").write_bytes(b"a variant")
    (base / "vae" / "diffusion_pytorch_model.bin").write_bytes(b"vae weights")
    control.mkdir(parents=True)
    (control / "config.json").write_text("{}")
    (control / "diffusion_pytorch_model.safetensors").write_bytes(b"controlnet weights")
    lora.mkdir()
    (lora / "pytorch_lora_weights.safetensors").write_bytes(b"lora v1")
    return base, control, lora


def test_a_run_records_each_model_file_it_read_by_name_and_hash(tmp_path):
    base, control, lora = local_models(tmp_path)
    models = {m["role"]: m for m in model_files_record(str(base), str(control), str(lora))}
    files = {f["path"]: f["sha256"] for f in models["base model"]["files"]}
    # The weights the loaders read (no variant; safetensors, else .bin) and the configs.
    assert (
        files["unet/diffusion_pytorch_model.safetensors"]
        == hashlib.sha256(b"unet weights").hexdigest()
    )
    assert "vae/diffusion_pytorch_model.bin" in files
    assert "unet/diffusion_pytorch_model.fp16.safetensors" not in files
    assert len(files) == 7
    assert models["base model"]["name"] == "sd" and models["base model"]["source"] == "local folder"
    assert models["depth ControlNet"]["name"] == "cn"
    assert models["species LoRA"]["name"] == "lora"
    assert models["species LoRA"]["files"][0]["sha256"] == hashlib.sha256(b"lora v1").hexdigest()
    # A model that cannot be read at the end of a run (a LoRA deleted meanwhile) is
    # recorded as such: the finished run is still written.
    gone = model_files_record(str(base), str(control), str(tmp_path / "deleted"))
    assert gone[2]["files"] == [] and gone[2]["sha256"] is None and "error" in gone[2]
    # One hash per model over its files' paths and hashes.
    again = model_files_record(str(base), str(control), str(lora))
    assert [m["sha256"] for m in again] == [m["sha256"] for m in models.values()]
    assert str(tmp_path) not in json.dumps(again)


def test_a_hub_cache_file_takes_its_blob_name_as_its_hash(tmp_path):
    from plantdreamer.guidance.model_files import file_sha256

    blob_hash = hashlib.sha256(b"not what the file holds").hexdigest()
    blobs, snapshot = tmp_path / "blobs", tmp_path / "snapshots" / "abc"
    blobs.mkdir()
    snapshot.mkdir(parents=True)
    (blobs / blob_hash).write_bytes(b"weights")
    (snapshot / "model.safetensors").symlink_to(blobs / blob_hash)
    # The hub names a weight file's blob by its SHA-256: nothing is read.
    assert file_sha256(snapshot / "model.safetensors", snapshot) == blob_hash
    # A file huggingface_hub downloaded into a folder: its recorded SHA-256 while unchanged.
    folder = tmp_path / "local"
    meta = folder / ".cache" / "huggingface" / "download" / "unet"
    meta.mkdir(parents=True)
    (folder / "unet").mkdir(exist_ok=True)
    weights = folder / "unet" / "w.safetensors"
    weights.write_bytes(b"weights")
    (meta / "w.safetensors.metadata").write_text(f"c0ffee\n{blob_hash}\n{9e9}\n")
    assert file_sha256(weights, folder) == blob_hash
    (meta / "w.safetensors.metadata").write_text(f"c0ffee\n{blob_hash}\n{1.0}\n")  # older
    assert file_sha256(weights, folder) == hashlib.sha256(b"weights").hexdigest()


HOSTILE = "bean | x\n## Licence: MIT\n<img src=x onerror=alert(1)> [a](https://e.example) *b* `c`"


class _Reader(HTMLParser):
    """The text and the tags of an HTML fragment."""

    def __init__(self) -> None:
        super().__init__()
        self.text: list[str] = []
        self.tags: list[str] = []

    def handle_starttag(self, tag: str, attrs: object) -> None:
        self.tags.append(tag)

    def handle_data(self, data: str) -> None:
        self.text.append(data)


def test_markdown_text_shows_any_text_as_itself():
    # A CommonMark renderer with GFM's tables and strikethrough (as the Hub renders cards;
    # markdown-it-py comes with rich) shows the escaped text as one paragraph of the text.
    from markdown_it import MarkdownIt

    from plantdreamer.text_escape import markdown_text

    renderer = MarkdownIt("commonmark").enable(["table", "strikethrough"])

    for text in (HOSTILE, "a_b_c 1. x", "- y", "\\`", "&amp; &lt;", "$x$ ~~s~~", "\u2028z"):
        reader = _Reader()
        reader.feed(renderer.render(markdown_text(text)))
        assert reader.tags == ["p"], text
        assert "".join(reader.text).strip() == " ".join(text.replace("\u2028", " ").split()), text
