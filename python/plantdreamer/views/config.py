"""The settings of the exported views, joined from the sections that read them: the rig
(``camera_rigs``), the background (``backgrounds``) and the jitter (``jitter``). Their
defaults are the views of before: the evaluation orbit on the grey of the renders."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from plantdreamer import settings
from plantdreamer.camera_rigs import ORBIT, RigConfig
from plantdreamer.settings import option_prefix
from plantdreamer.views.backgrounds import BackgroundConfig
from plantdreamer.views.jitter import JitterConfig


@dataclass
class ViewsConfig:
    rig: RigConfig = field(default_factory=RigConfig, metadata=option_prefix(""))
    background: BackgroundConfig = field(
        default_factory=BackgroundConfig, metadata=option_prefix("")
    )
    jitter: JitterConfig = field(default_factory=JitterConfig, metadata=option_prefix(""))

    @classmethod
    def from_settings(cls, values: Mapping[str, Any]) -> ViewsConfig:
        """The sections with the settings of ``values`` that are theirs (by name)."""
        config = cls()
        for s in settings.walk(cls):
            if s.name in values:
                setattr(getattr(config, s.path[0]), s.path[1], values[s.name])
        for section in (config.rig, config.background):
            section.__post_init__()  # ranges given as lists
        return config

    @property
    def plain(self) -> bool:
        """The views of before: the orbit, on grey, as rendered."""
        return self.rig.rig == ORBIT and self.background.plain and self.jitter.off

    def validate(self) -> None:
        """Each section's settings, and a real rig's file read (before anything runs)."""
        self.rig.validate()
        self.background.validate()
        if self.rig.rig_transforms is not None:
            from plantdreamer.views.real_rig import rig_cameras

            rig_cameras(self.rig.rig_transforms)
