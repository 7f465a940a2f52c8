"""A dataset's plant: its folder name (id), its full config and the hash that tells whether
its finished files are up to date (settings and the input file's contents)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass

from plantdreamer import settings
from plantdreamer.exports.listing import species_name
from plantdreamer.pipeline.outputs import WATCHING
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.views import ViewsConfig

# Settings added since the manifests' hashes began: the full-grown stage and the leaves'
# occlusion at their defaults hash as before them.
LATER_SETTINGS = ("growth", "growth-since", "leaf-occlusion")


@dataclass(frozen=True)
class Plant:
    """One plant of the dataset: its folder name and the full config of its run."""

    id: str
    group: str
    config: GenerateConfig
    config_hash: str

    @property
    def species(self) -> str | None:
        return self.config.source.species

    @property
    def species_name(self) -> str:
        """Its species as the dataset's splits and card count it (``exports.listing``)."""
        return species_name(self.config.source.species, self.config.source.pointcloud)

    @property
    def source(self) -> str:
        return self.config.source.pointcloud or "lsystem"


def config_hash(cfg: GenerateConfig, source_digest: str | None = None) -> str:
    """A stable hash of every setting (sorted JSON) and of the input file's contents
    (``source_digest``), to tell whether a plant is up to date. It hashes the config's
    sections (the saved form of 689da5e), so the manifests of datasets made before records
    used setting names still match their plants, and leaves out the settings that only
    watch a run (``outputs.WATCHING``: progress pictures, TensorBoard), the exported
    views' section at its defaults (the orbit on grey) and the ``LATER_SETTINGS`` at
    theirs, so the manifests of datasets made before them match too (their plants lack
    only traits.json: the dataset's export names them)."""
    data = dataclasses.asdict(cfg)
    for s in settings.walk(GenerateConfig):
        *sections, name = s.path
        held = data
        for section in sections:
            held = held[section]
        # Watching a run changes none of its plant; a later setting at its default makes
        # the plant of before it.
        if s.name in WATCHING or (s.name in LATER_SETTINGS and held[name] == s.default):
            del held[name]
    if cfg.outputs.views == ViewsConfig():  # the views of before they were settings: as then
        del data["outputs"]["views"]
    text = json.dumps(data, sort_keys=True, separators=(",", ":"))
    if source_digest is not None:
        text += f"|source:{source_digest}"
    return hashlib.sha256(text.encode()).hexdigest()[:16]
