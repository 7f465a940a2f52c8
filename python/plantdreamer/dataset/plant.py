"""A dataset's plant: its folder name (id), its full config and the hash that tells whether
its finished files are up to date (settings and the input file's contents)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass

from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.views import ViewsConfig


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
    def source(self) -> str:
        return self.config.source.pointcloud or "lsystem"


def config_hash(cfg: GenerateConfig, source_digest: str | None = None) -> str:
    """A stable hash of every setting (sorted JSON) and of the input file's contents
    (``source_digest``), to tell whether a plant is up to date. It hashes the config's
    sections (the saved form of 689da5e), so the manifests of datasets made before records
    used setting names still match their plants; the exported views' section is left out
    at its defaults (the orbit on grey), so plants made before it still match too."""
    data = dataclasses.asdict(cfg)
    if cfg.outputs.views == ViewsConfig():  # the views of before they were settings: as then
        del data["outputs"]["views"]
    text = json.dumps(data, sort_keys=True, separators=(",", ":"))
    if source_digest is not None:
        text += f"|source:{source_digest}"
    return hashlib.sha256(text.encode()).hexdigest()[:16]
