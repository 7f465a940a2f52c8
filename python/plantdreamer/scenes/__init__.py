"""Scenes: several finished plants together, as on a tray or a bench, rendered in one pass
per view with their labels (``make_scene``); the plants are read from their folders, never
trained again."""

from __future__ import annotations

from plantdreamer.scenes.config import SceneConfig
from plantdreamer.scenes.make import SceneResult, make_scene, scene_settings

__all__ = ["SceneConfig", "SceneResult", "make_scene", "scene_settings"]
