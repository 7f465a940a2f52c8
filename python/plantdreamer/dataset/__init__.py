"""Datasets of many plants: a spec of groups, one trainer per packed group of plants (a
plant alone is a group of one), run by long-lived workers: processes of this machine (the
local pool), or Ray actors on a cluster.

``request`` checks what a front end asked for (the command line and ``make_dataset`` call
it), ``spec`` parses the TOML spec into plants (``plant``), ``packing`` groups them B per
GPU, ``plan`` decides which to skip, resume or redo, ``runner`` runs and records them,
``scheduler`` hands them to the workers (``workers``: the local pool or Ray; ``worker``:
what keeps the models loaded), ``tasks`` is what runs on a worker, ``manifest`` records
every plant, ``engine`` talks to Ray.
"""

from plantdreamer.dataset.plant import Plant, config_hash
from plantdreamer.dataset.runner import DatasetReport, RunOptions, run_dataset
from plantdreamer.dataset.spec import expand, load_spec

__all__ = [
    "DatasetReport",
    "Plant",
    "RunOptions",
    "config_hash",
    "expand",
    "load_spec",
    "run_dataset",
]
