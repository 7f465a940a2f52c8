"""Phenotypes as ground truth (docs/traits.md): a plant's and each leaf's traits from an
L-System's mesh and skeleton (``plant``) or a scan's labelled points (``points``), the same
figures on the trained Gaussians, and per view the visible leaves, their occlusion
(``occlusion``) and the plant's size in pixels (``views``); ``record`` assembles the record
and ``files`` reads and writes ``traits.json``, ``counts`` the per-view CSV files. The
names here are torch-free (``record`` and ``occlusion`` render, with torch).
"""

from __future__ import annotations

from plantdreamer.traits.files import TRAITS_FILE, read_traits, recorded_views, write_traits
from plantdreamer.traits.views import ViewRecorder, map_figures, visible_fractions

__all__ = [
    "TRAITS_FILE",
    "ViewRecorder",
    "map_figures",
    "read_traits",
    "recorded_views",
    "visible_fractions",
    "write_traits",
]
