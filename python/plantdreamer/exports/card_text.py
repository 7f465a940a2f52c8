"""The fixed texts of a dataset's card and the sections written from its figures: the
licence terms of the images, the citation, the models' lines and the limitations. Every
user-given name goes through ``markdown_text`` (``md``) where it is written."""

from __future__ import annotations

from typing import Any

from plantdreamer.exports.card_models import recorded_setting
from plantdreamer.text_escape import markdown_text as md

GUIDED_TERMS = (
    "The images of plants trained with diffusion guidance are outputs of the models listed "
    "above; each model's licence says what it asks of its outputs."
)
SD_OUTPUT_TERMS = (
    "The images of plants trained with diffusion guidance are outputs of Stable Diffusion "
    "2.1 (with a depth ControlNet and any species LoRA). Its weights are licensed under the "
    "CreativeML Open RAIL++-M licence, which claims no rights in the outputs you generate but "
    "makes you accountable for them and their use: no use of them may break the use-based "
    "restrictions of the licence's Attachment A, and whoever shares the weights (or a model "
    "derived from them) passes those restrictions on. The ControlNet and LoRA weights carry "
    "their own licences (see their model cards). A summary, not legal advice."
)
RENDER_TERMS = (
    "Plants made without diffusion guidance are renders of the procedural plants or point "
    "clouds alone: no model weights went into them, and their licence is the maker's to "
    "choose (with that of any scan they were made from)."
)
CITATION = """@inproceedings{hartley2025plantdreamer,
  title     = {PlantDreamer: Achieving Realistic 3D Plant Models with Diffusion-Guided Gaussian Splatting},
  author    = {Hartley, Zane K. J. and Stuart, Lewis A. G. and French, Andrew P. and Pound, Michael P.},
  booktitle = {Proceedings of the IEEE/CVF International Conference on Computer Vision (ICCV)},
  year      = {2025},
  eprint    = {2505.15528},
  archivePrefix = {arXiv}
}"""


def model_lines(models: list[dict[str, Any]]) -> list[str]:
    """One line per model: its name, where from, and the SHA-256 over the files it read."""
    if not models:
        return ["- none: every plant was made without diffusion guidance"]
    lines = []
    for m in models:
        where = m["source"] + (f", revision {md(m['revision'])}" if m["revision"] else "")
        if m["sha256"]:
            what = f"SHA-256 {md(m['sha256'])} over its {len(m['files'])} files read"
        else:
            what = "no hash: made before plantdreamer recorded the files a plant read"
        plants = f"{m['plants']} plant{'s' if m['plants'] != 1 else ''}"
        lines.append(f"- {m['role']}: {md(m['name'])} ({where}; {what}; {plants})")
    lines.append("")
    lines.append("`dataset.json` lists each model's files with their SHA-256 (`card.models`).")
    return lines


def limitations(card: dict[str, Any]) -> list[str]:
    """What the data does not show: it is synthetic, seen from the cameras and on the
    backgrounds its distributions list (one orbit on grey unless rigs, photos or scenes
    were asked for), labelled from the 3D model."""
    v, d = card["views"], card.get("distributions") or {}
    orbits = all(text.startswith("orbit") for text in d.get("cameras", {"orbit": 1}))
    grey = all(text.startswith("grey") for text in d.get("backgrounds", {"grey": 1}))
    scenes = bool(d.get("scenes", {}).get("count"))
    if orbits:
        cameras = (
            f"- Cameras: each plant is seen from one orbit of {md(v['per_plant'])} views at "
            f"{md(v['elevation_deg'])} degrees of elevation, a vertical field of view of "
            f"{md(v['fovy_deg'])} degrees and {md(v['pixels'])} pixels square; no other "
            "viewpoints, lenses or motion."
        )
    else:
        cameras = (
            "- Cameras: the rigs the distributions above list, each a pinhole camera: no "
            "lens distortion, sensor noise or motion."
        )
    if grey and not scenes:
        background = (
            f"- Background: flat grey of level {md(v['background'])} (0 black, 1 white) behind "
            "every plant; no scenes, clutter, other plants or lighting changes."
        )
    else:
        background = (
            "- Backgrounds: as the distributions above list, composited behind the plants with "
            "their alpha: plant and background never share light, shadow or perspective."
        )
    return [
        "- Synthetic plants: L-System plants and any point clouds given, textured by the "
        "diffusion models above or left in their initial colours; no plant was photographed, "
        "and their realism was not measured here.",
        cameras,
        background,
        "- Labels come from the 3D model's Gaussians (each with its organ and leaf), not from "
        "annotators: they are exact for the model, which is itself an approximation of a plant.",
    ]


def plant_views(configs: list[dict[str, Any]]) -> dict[str, str]:
    """The plants' evaluation views as the limitations name them: each setting's values
    over the plants (``a or b``), ``framed`` for a distance the run chose."""

    def values(name: str, section: str) -> str:
        found = sorted({str(recorded_setting(c, name, section)) for c in configs} - {"None"})
        return " or ".join(found) or "unknown"

    return {
        "per_plant": values("eval-views", "outputs"),
        "elevation_deg": values("eval-elevation-deg", "outputs"),
        "fovy_deg": values("eval-fovy-deg", "outputs"),
        "pixels": values("resolution", "train"),
        "background": values("background", "train"),
    }
