"""``plantdreamer dataset --help``'s examples (its epilog), kept apart from the command."""

from __future__ import annotations

# \b keeps click from rewrapping the lines that follow it.
DATASET_EXAMPLES = """Examples:

\b
  # what a run would make, resume or skip; nothing starts
  plantdreamer dataset spec.toml --out ds --dry-run
  # the plants of a spec file (docs/spec.md) on this machine
  plantdreamer dataset spec.toml --out ds
  # no spec: two species, eight plants each, without weights (a CPU is enough)
  plantdreamer dataset --species bean --species mint --seeds 0-7 --guidance none --out ds
  # 16 plants trained together on each GPU of a Ray cluster (docs/cluster.md)
  plantdreamer dataset spec.toml --out /shared/ds --address HEAD_IP:6379 --plants-per-gpu 16
  # any generate setting for every plant, and the share of plants in each split
  plantdreamer dataset spec.toml --out ds --set steps=1200 --split 0.8,0.1,0.1

\b
Run the same command again to continue: finished plants are skipped, stopped ones resume.
"""
