"""Known-answer models on disk: made once per spec, in diffusers' layout, reused after.

``build_models`` writes ``base/`` (like ``stabilityai/stable-diffusion-2-1-base``) and
``controlnet/`` (like ``thibaud/controlnet-sd21-depth-diffusers``), so ``generate`` loads
them through its real loader (``--base-model``, ``--controlnet``), and ``manifest.json``:
the spec, the library versions, training figures and the SHA-256 of every file, which is
how a rebuild is checked to be bit for bit the same.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from plantdreamer.known_answer.spec import GENERATOR_VERSION, KnownAnswerSpec, library_versions
from plantdreamer.thread_policy import pinned_torch_threads

MANIFEST = "manifest.json"


def default_cache() -> Path:
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "plantdreamer" / "known_answer"


def file_hashes(folder: Path) -> dict[str, str]:
    """SHA-256 of every file under ``folder`` but the manifest (relative POSIX paths)."""
    out = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file() and p.name != MANIFEST):
        out[path.relative_to(folder).as_posix()] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def machine_of() -> dict[str, str]:
    """Where a set is built: the same spec and libraries give other bits on another machine
    (measured: a rebuild of the committed set on another x86-64 CPU differed in every
    trained file, docs/known_answer.md "Bits and CPUs"), so a failed ``--verify`` says both."""
    import numpy
    import torch

    from plantdreamer.versions import cpu_model

    return {
        "cpu": cpu_model(),
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "numpy": numpy.__version__,
    }


def differing_files(manifest: dict[str, Any], rebuilt: dict[str, Any]) -> str | None:
    """None when a rebuild has every file of ``manifest`` bit for bit; else what differs,
    with the machines both were built on."""
    differ = sorted(
        k
        for k in set(manifest["sha256"]) | set(rebuilt["sha256"])
        if manifest["sha256"].get(k) != rebuilt["sha256"].get(k)
    )
    if not differ:
        return None

    def where(m: dict[str, Any]) -> str:
        built_on = m.get("built_on")
        if not built_on:
            return "an unrecorded machine"
        return ", ".join(f"{k} {v}" for k, v in sorted(built_on.items()))

    return (
        f"rebuilt models differ in {', '.join(differ)} (built on {where(manifest)}; "
        f"rebuilt on {where(rebuilt)}): bits are reproducible on the kind of machine that "
        "built them"
    )


def model_dirs(folder: Path) -> tuple[Path, Path]:
    return folder / "base", folder / "controlnet"


def build_models(
    spec: KnownAnswerSpec, out: Path, log: Any = None, threads: int = 1
) -> dict[str, Any]:
    """Render the plant's true views, train the tiny models on them (on ``threads`` CPU
    threads: another count gives other bits) and save everything in ``out`` (made in a
    temporary folder beside it, then renamed: never half written)."""
    from plantdreamer.guidance.config import SDS_DEFAULTS
    from plantdreamer.guidance.models import save_components
    from plantdreamer.guidance.tiny import tiny_models
    from plantdreamer.known_answer import training, views

    say = log or (lambda _msg: None)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    figures: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=".known-answer-") as tmp:
        work = Path(tmp)
        with pinned_torch_threads(threads):
            t0 = time.perf_counter()
            truth = views.true_gaussians(spec, work)
            data = views.training_views(spec, truth)
            figures["views_seconds"] = time.perf_counter() - t0
            say(f"rendered {len(data.images)} true views in {figures['views_seconds']:.0f} s")
            parts = tiny_models(spec.seed)
            parts.unet, parts.controlnet = training.denoiser(spec.denoiser_width, spec.seed)
            t0 = time.perf_counter()
            figures.update(training.train_vae(parts.vae, data, spec))
            figures["vae_seconds"] = time.perf_counter() - t0
            say(f"trained the VAE in {figures['vae_seconds']:.0f} s")
            t0 = time.perf_counter()
            negative = SDS_DEFAULTS.negative_prompt
            figures.update(training.train_denoiser(parts, data, spec, negative))
            figures["denoiser_seconds"] = time.perf_counter() - t0
            say(f"trained the UNet and ControlNet in {figures['denoiser_seconds']:.0f} s")
        staged = work / "models"
        save_components(parts, staged)
        manifest = {
            "spec": spec.to_dict(),
            "threads": threads,
            "generator": GENERATOR_VERSION,
            "versions": library_versions(),
            "built_on": machine_of(),
            "figures": {k: round(float(v), 6) for k, v in figures.items()},
            "sha256": file_hashes(staged),
        }
        (staged / MANIFEST).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
        if out.exists():
            shutil.rmtree(out)
        staged.rename(out)
    return manifest


def cached_models(
    spec: KnownAnswerSpec, cache: Path | None = None, log: Any = None, threads: int = 1
) -> Path:
    """The folder of this spec's models, built first if the cache does not hold them."""
    suffix = "" if threads == 1 else f"-t{threads}"
    folder = (cache or default_cache()) / (spec.key() + suffix)
    if not (folder / MANIFEST).is_file():
        build_models(spec, folder, log, threads)
    return folder


def untrained_models(spec: KnownAnswerSpec, cache: Path | None = None) -> Path:
    """The control: the same tiny models before any training (random weights)."""
    from plantdreamer.guidance.tiny import save_tiny_models

    folder = (cache or default_cache()) / f"untrained-s{spec.seed}"
    if not (folder / "controlnet" / "config.json").is_file():
        save_tiny_models(folder, spec.seed)
    return folder
