"""The card's distributions: how the dataset's views were made (their cameras, backgrounds,
jitter) and its scenes, read from each plant's ``run.json`` and each scene's ``scene.json``,
with the limits of synthetic views a model trained on them should be tested against."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

from plantdreamer.camera_rigs import ORBIT, RIGS, TRANSFORMS, RigConfig
from plantdreamer.exports.listing import PlantEntry, scene_record
from plantdreamer.text_escape import markdown_text as md

SIM_TO_REAL = (
    "Synthetic views, not photographs: the plants are L-System models or scans trained as "
    "Gaussian splats, lit as their training left them (no shadows cast on the background, "
    "no specular highlights from a real light), rendered by a pinhole camera without lens "
    "distortion, noise, motion blur or depth of field. Backgrounds are photos composited "
    "behind the plant with its alpha, so plant and background never share light or "
    "perspective, and nothing stands in front of a plant but other plants. Test a model "
    "trained here on real images of your own rig before trusting it there."
)


def _range(value: Any) -> str:
    low, high = value
    return f"{low:g}" if low == high else f"{low:g} to {high:g}"


def camera_text(config: dict[str, Any]) -> str:
    """One plant's cameras in words, from its recorded settings."""
    rig = config.get("rig") or ORBIT
    views = config.get("eval-views", 120)
    if rig == ORBIT:
        return (f"orbit: {views} views at elevation {config.get('eval-elevation-deg', 15):g} "
                f"deg, field of view {config.get('eval-fovy-deg', 70):g} deg")  # fmt: skip
    if rig == TRANSFORMS:
        return f"a real rig's cameras ({Path(str(config.get('rig-transforms'))).name})"
    if rig not in RIGS:
        return str(rig)
    names = ("elevation_deg", "azimuth_deg", "distance", "roll_deg", "fovy_deg")
    given = {n: config.get("rig-" + n.replace("_", "-")) for n in names}
    dist = RigConfig(rig, **{f"rig_{n}": v for n, v in given.items()}).distribution()
    fovy = _range(dist.fovy_deg) if dist.fovy_deg else f"{config.get('eval-fovy-deg', 70):g}"
    return (
        f"{rig}: {views} views, elevation {_range(dist.elevation_deg)} deg, azimuth "
        f"{_range(dist.azimuth_deg)} deg{' (even)' if dist.even else ''}, distance "
        f"{_range(dist.distance)} framed, roll {_range(dist.roll_deg)} deg, field of view "
        f"{fovy} deg"
    )


def background_text(config: dict[str, Any]) -> str:
    if config.get("background-images"):
        return f"photos from {Path(str(config['background-images'])).name}/, one per view"
    if config.get("background-colour"):
        return "colour " + " ".join(f"{c:g}" for c in config["background-colour"])
    return f"grey {config.get('background', 0.75):g}"


def jitter_text(config: dict[str, Any]) -> str:
    parts = [(k, config.get(f"jitter-{k}") or 0) for k in ("brightness", "contrast")]
    parts.append(("white balance", config.get("jitter-white-balance") or 0))
    shown = [f"{name} +-{value:g}" for name, value in parts if value]
    return ", ".join(shown) or "off"


def distributions(configs: dict[str, dict[str, Any]], scenes: list[PlantEntry]) -> dict:
    """The card's ``distributions``: plants per camera, background and jitter setting,
    the scenes (count per split, plants per scene, layouts) and the sim-to-real limits."""
    texts = {"cameras": camera_text, "backgrounds": background_text, "jitter": jitter_text}
    tally: dict[str, Any] = {
        key: dict(Counter(text(c) for c in configs.values()).most_common())
        for key, text in texts.items()
    }
    records = [scene_record(s) for s in scenes]
    layouts = Counter(
        f"{len(r.get('plants', []))} plants, {r.get('settings', {}).get('scene-layout', '?')}"
        for r in records
    )
    tally["scenes"] = {
        "count": len(scenes),
        "splits": dict(Counter(str(r.get("split")) for r in records)),
        "layouts": dict(layouts),
        "cameras": dict(Counter(camera_text(r.get("settings", {})) for r in records)),
    }
    tally["limits"] = SIM_TO_REAL
    return tally


def distributions_markdown(card: dict[str, Any]) -> list[str]:
    """The card's section on its distributions (README.md)."""
    d = card.get("distributions")
    if not d:
        return []
    lines = ["## Distributions", "", "Plants per setting of their views:", ""]
    for key in ("cameras", "backgrounds", "jitter"):  # names a user gave (folders): escaped
        lines += [f"- {key}: " + "; ".join(f"{md(text)} ({n})" for text, n in d[key].items())]
    scenes = d["scenes"]
    if scenes["count"]:
        splits = ", ".join(f"{n} {md(s)}" for s, n in sorted(scenes["splits"].items()))
        layouts = "; ".join(f"{md(t)} ({n})" for t, n in scenes["layouts"].items())
        cameras = "; ".join(f"{md(t)} ({n})" for t, n in scenes["cameras"].items())
        lines += [
            f"- scenes: {scenes['count']} ({splits}), each of one split's plants: {layouts}; "
            f"cameras {cameras}"
        ]
    lines += ["", f"Limits: {d['limits']}", ""]
    return lines
