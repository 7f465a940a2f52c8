"""What the Python API returns: a finished plant's folder and files (``GeneratedPlant``), a
dataset's (``DatasetResult``); every path absolute."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["DatasetResult", "GeneratedPlant"]


@dataclass(frozen=True)
class GeneratedPlant:
    """A finished plant folder: the files a caller opens next and the run's figures."""

    folder: Path
    ply: Path  # the 3DGS model (INRIA layout, labels as ``label`` / ``instance``)
    steps: int
    gaussians: int
    seconds: float  # wall-clock time of the call that made it (0 for a plant already made)
    timings: dict[str, float] = field(default_factory=dict)  # seconds per phase (run.json)

    @property
    def renders(self) -> list[Path]:
        """The evaluation orbit's views (``renders/view_NNN.png``)."""
        return sorted((self.folder / "renders").glob("view_*.png"))

    @property
    def turntable(self) -> Path | None:
        found = [self.folder / f"turntable.{s}" for s in ("gif", "mp4")]
        return next((p for p in found if p.is_file()), None)

    @property
    def progress(self) -> Path:
        """The Gaussians at each checkpoint, side by side (``progress.png``)."""
        from plantdreamer.pipeline.progress_pictures import PROGRESS_STRIP

        return self.folder / PROGRESS_STRIP

    @property
    def loss_plot(self) -> Path | None:
        """``loss.png`` (None for a run without guidance: it has no loss)."""
        from plantdreamer.pipeline.progress_pictures import LOSS_PLOT

        path = self.folder / LOSS_PLOT
        return path if path.is_file() else None

    @property
    def log(self) -> Path:
        """``log.csv``: one row per trained step."""
        return self.folder / "log.csv"

    @property
    def record(self) -> Path:
        """``run.json``: every setting, versions, timings."""
        return self.folder / "run.json"

    @property
    def coco(self) -> Path | None:
        """The plant's COCO file (None for an unlabelled plant)."""
        from plantdreamer.exports.plant import COCO_FILE

        path = self.folder / COCO_FILE
        return path if path.is_file() else None

    @property
    def traits(self) -> Path:
        """``traits.json``: the plant's and each leaf's traits, the trained Gaussians'
        figures and each view's (docs/traits.md)."""
        from plantdreamer.traits import TRAITS_FILE

        return self.folder / TRAITS_FILE

    @property
    def counts(self) -> Path | None:
        """``counts.csv``: each view's visible leaves and plant size in pixels (None for
        an unlabelled plant)."""
        from plantdreamer.traits.counts import COUNTS_FILE

        path = self.folder / COUNTS_FILE
        return path if path.is_file() else None


@dataclass(frozen=True)
class DatasetResult:
    """A dataset folder after a run: its plants, splits and label files."""

    folder: Path
    done: int  # plants made by this call
    skipped: int  # plants already complete in the folder
    seconds: float
    splits: dict[str, list[str]]  # split -> plant ids
    plants: list[Path]  # every finished plant folder
    scenes: list[Path] = field(default_factory=list)  # every finished scene folder

    @property
    def coco(self) -> dict[str, Path]:
        """``coco/<split>.json`` by split."""
        return {s: self.folder / "coco" / f"{s}.json" for s in self.splits}

    @property
    def counts(self) -> dict[str, Path]:
        """``counts/<split>.csv`` by split: each view's visible leaves and plant size."""
        from plantdreamer.traits.counts import COUNTS_DIR

        return {s: self.folder / COUNTS_DIR / f"{s}.csv" for s in self.splits}

    @property
    def yolo(self) -> Path:
        """``yolo/data.yaml`` (Ultralytics' dataset file)."""
        return self.folder / "yolo" / "data.yaml"

    @property
    def gallery(self) -> Path:
        return self.folder / "gallery.png"

    @property
    def card(self) -> Path:
        """The dataset's card, ``README.md`` (also under ``card`` in ``dataset.json``)."""
        from plantdreamer.exports.card import README_FILE

        return self.folder / README_FILE
