"""Datasets of many plants: a spec of groups, one `generate` per plant, scheduled on Ray.

``spec`` parses the TOML spec into plants, ``runner`` plans and schedules them, ``tasks``
is what runs on a worker, ``manifest`` records every plant, ``engine`` talks to Ray.
"""

from plantdreamer.dataset.runner import DatasetReport, RunOptions, run_dataset
from plantdreamer.dataset.spec import Plant, config_hash, expand, load_spec

__all__ = [
    "DatasetReport",
    "Plant",
    "RunOptions",
    "config_hash",
    "expand",
    "load_spec",
    "run_dataset",
]
