"""Watching a run: ``loss.png``'s panels and running mean, the progress pictures at their
cadence, and the TensorBoard writer (scalars, pictures, a resume's purge), without training:
the trainer's calls are made here in its order, on a plant at its start."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from plantdreamer.errors import PlantDreamerError
from plantdreamer.pipeline.log_plot import (
    RUNNING_MIN,
    loss_figure,
    running_mean,
    running_window,
    write_loss_plot,
)
from plantdreamer.pipeline.outputs import samples_cell
from plantdreamer.pipeline.progress_pictures import ProgressPictures
from plantdreamer.pipeline.run_observers import run_observers
from plantdreamer.pipeline.settings.config import GenerateConfig


def sds_rows(steps: int, start: int = 0, loss: bool = True) -> list[dict]:
    """Rows as the SDS guidance logs them (``log.csv``'s columns and cells), each step's its
    own whatever the range; without ``loss``, the guidance's other figures only."""
    rows = []
    for s in range(start, steps):
        rng = np.random.default_rng(s)
        rows.append(
            {"step": s, "loss": float(200 + 50 * rng.random() - s), "gaussians": 300,
             "grad_norm": float(20 + rng.random()), "timestep": 500.0,
             "timesteps": samples_cell([float(rng.integers(200, 981))]), "t_min": 200.0,
             "t_max": 980.0 - s, "grad_clip": float("nan"), "nonfinite_grad": 0.0}
        )  # fmt: skip
        if not loss:
            del rows[-1]["loss"]
    return rows


def slow_running_mean(values, window):
    return [float(np.mean(values[max(0, i + 1 - window) : i + 1])) for i in range(len(values))]


def test_running_mean_is_the_trailing_mean_of_each_step():
    values = np.random.default_rng(0).normal(size=37)
    for window in (1, 3, 10, 37, 100):
        np.testing.assert_allclose(running_mean(values, window), slow_running_mean(values, window))
    assert running_window(30) == RUNNING_MIN and running_window(3600) == 72


def test_loss_plot_has_a_panel_per_logged_figure_and_a_running_mean_under_100_steps(tmp_path):
    rows = sds_rows(30)
    figure = loss_figure(rows)
    axes = figure.get_axes()
    assert [a.get_ylabel() for a in axes] == ["loss", "timestep", "gradient norm"]
    loss, mean = axes[0].get_lines()
    np.testing.assert_array_equal(loss.get_ydata(), [r["loss"] for r in rows])
    assert mean.get_label() == f"mean of {RUNNING_MIN} steps"
    np.testing.assert_allclose(mean.get_ydata(), slow_running_mean(loss.get_ydata(), RUNNING_MIN))
    (drawn,) = axes[1].get_lines()  # the plant's own draws, from its timesteps cell
    np.testing.assert_array_equal(drawn.get_ydata(), [float(r["timesteps"]) for r in rows])
    (bounds,) = axes[1].collections
    low, high = (
        bounds.get_paths()[0].vertices[:, 1].min(),
        bounds.get_paths()[0].vertices[:, 1].max(),
    )
    assert (low, high) == (200.0, 980.0)
    grad, grad_mean = axes[2].get_lines()
    np.testing.assert_array_equal(grad.get_ydata(), [r["grad_norm"] for r in rows])
    assert grad_mean.get_label().startswith("mean of")
    # A fit that logs only its loss has one panel; a run without a loss has no plot.
    only_loss = [{"step": s, "loss": 1.0 / (s + 1), "gaussians": 10} for s in range(5)]
    assert [a.get_ylabel() for a in loss_figure(only_loss).get_axes()] == ["loss"]
    assert loss_figure([{"step": 0, "loss": None}]) is None
    assert not write_loss_plot(tmp_path / "none.png", []) and not (tmp_path / "none.png").exists()
    # The same rows, the same bytes.
    assert write_loss_plot(tmp_path / "a.png", rows) and write_loss_plot(tmp_path / "b.png", rows)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()


@pytest.fixture(scope="module")
def start_state():
    from plantdreamer.pipeline.state.run_state import RunState

    cfg = GenerateConfig.of(species="bean", points=300, resolution=32, guidance="none")
    return cfg, RunState.fresh(cfg, show_progress=False)


def trained(observers, plant, steps: int, checkpoint_every: int, start: int = 0, stop=None):
    """The trainer's calls to its observers (trainer.py) for steps ``start`` to ``steps``, the
    plant's log growing as ``plant.rows`` says (None: none, as without guidance); ``stop``: a
    step after which the run is killed (its observers closed, no further checkpoint)."""
    for step in range(start, steps):
        if plant.rows is not None:
            plant.state.log_rows += plant.rows(step + 1, step)
        for o in observers:
            o.step_end(step, [plant], None)
        if step == stop:
            break
        if (step + 1) % checkpoint_every == 0 and step + 1 < steps:
            for o in observers:
                o.checkpoint(step + 1, [plant])
    else:
        for o in observers:
            o.checkpoint(steps, [plant])
    for o in observers:
        o.train_end()


def plant_at_start(start_state, folder: Path, steps: int, rows=None, **outputs):
    """A ``PlantRun`` at step 0 of ``steps``, checkpoints every 4, its log made by ``rows``."""
    import copy

    from plantdreamer.pipeline.step.plant import PlantRun

    cfg, state = copy.deepcopy(start_state)
    cfg.train.steps, cfg.train.checkpoint_every = steps, 4
    for name, value in outputs.items():
        setattr(cfg.outputs, name, value)
    folder.mkdir()
    plant = PlantRun(cfg, state, folder)
    plant.rows = rows  # type: ignore[attr-defined]
    return plant


def test_progress_pictures_come_at_the_checkpoints_or_at_their_own_cadence(start_state, tmp_path):
    from PIL import Image

    default = plant_at_start(start_state, tmp_path / "default", 10)  # no log: no loss.png
    trained(run_observers(default.cfg.outputs), default, 10, 4)
    frames = sorted(p.name for p in (default.out_dir / "progress").iterdir())
    assert frames == ["step_000004.png", "step_000008.png", "step_000010.png"]
    heard = []
    every = plant_at_start(start_state, tmp_path / "every", 10, progress_every=3)
    pictures = ProgressPictures(3, [lambda p, done, frame: heard.append((p, done, frame))])
    trained([pictures], every, 10, 4)
    frames = sorted(p.name for p in (every.out_dir / "progress").iterdir())
    assert frames == ["step_000003.png", "step_000006.png", "step_000009.png", "step_000010.png"]
    assert [(p, done) for p, done, _ in heard] == [(every, d) for d in (3, 6, 9, 10)]
    with Image.open(every.out_dir / "progress" / "step_000010.png") as png:
        np.testing.assert_array_equal(np.asarray(png), heard[-1][2])
    with Image.open(every.out_dir / "progress.png") as strip:
        assert strip.width == 4 * 128
    assert not (every.out_dir / "loss.png").exists()  # a run without a loss: no plot


def test_tensorboard_is_a_setting_whose_missing_package_is_one_clear_error(monkeypatch):
    import importlib.util

    from plantdreamer.pipeline.tensorboard_writer import TensorBoardWriter

    cfg = GenerateConfig.of(species="bean", tensorboard=True)
    cfg.validate()
    pictures, writer = run_observers(cfg.outputs)
    assert isinstance(writer, TensorBoardWriter) and pictures.listeners == [writer.picture]
    assert len(run_observers(GenerateConfig.of(species="bean").outputs)) == 1
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda n, *a: None if n == "tensorboard" else find_spec(n, *a)
    )
    with pytest.raises(PlantDreamerError, match=r"pip install 'plantdreamer\[tensorboard\]'"):
        cfg.validate()


def read_events(folder: Path) -> tuple[dict, dict]:
    """Scalars ({tag: [(step, value)]}) and pictures ({step: PNG bytes}) as TensorBoard
    reads the folder (its purge of what a resumed run wrote again included)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(folder), size_guidance={"scalars": 0, "images": 0})
    events.Reload()
    tags = events.Tags()
    scalars = {t: [(e.step, e.value) for e in events.Scalars(t)] for t in tags["scalars"]}
    images = {e.step: e.encoded_image_string for e in events.Images("progress")}
    return scalars, images


def test_tensorboard_events_of_a_resumed_run_equal_an_unbroken_runs(start_state, tmp_path):
    """Scalars and pictures as TensorBoard reads them, after a kill past the checkpoint a
    resume starts from. (The rows hold no loss, so no loss.png is drawn: tested above.)"""
    pytest.importorskip("tensorboard")
    from PIL import Image

    from plantdreamer.pipeline.tensorboard_writer import TENSORBOARD_DIR

    def figures(steps, start):
        return sds_rows(steps, start, loss=False)

    unbroken = plant_at_start(start_state, tmp_path / "unbroken", 10, figures, tensorboard=True)
    trained(run_observers(unbroken.cfg.outputs), unbroken, 10, 4)
    scalars, images = read_events(unbroken.out_dir / TENSORBOARD_DIR)
    rows = figures(10, 0)
    assert scalars["grad_norm"] == [(r["step"], pytest.approx(r["grad_norm"])) for r in rows]
    assert scalars["timesteps"] == [(r["step"], float(r["timesteps"])) for r in rows]
    assert scalars["t_max"] == [(r["step"], r["t_max"]) for r in rows]
    assert "grad_clip" not in scalars  # NaN: no clip, not a figure
    assert sorted(images) == [3, 7, 9]  # the pictures after 4, 8 and 10 steps
    with Image.open(io.BytesIO(images[9])) as picture:
        with Image.open(unbroken.out_dir / "progress" / "step_000010.png") as png:
            np.testing.assert_array_equal(np.asarray(picture), np.asarray(png))
    # Killed after step 6 (its events of steps 4-6 on disk), resumed from the checkpoint
    # at 4 with the log the checkpoint holds.
    cut = plant_at_start(start_state, tmp_path / "cut", 10, figures, tensorboard=True)
    trained(run_observers(cut.cfg.outputs), cut, 10, 4, stop=6)
    assert read_events(cut.out_dir / TENSORBOARD_DIR)[0]["grad_norm"][-1][0] == 6
    cut.state.log_rows = cut.state.log_rows[:4]
    trained(run_observers(cut.cfg.outputs), cut, 10, 4, start=4)
    assert len(list((cut.out_dir / TENSORBOARD_DIR).iterdir())) == 2  # a file per session
    assert read_events(cut.out_dir / TENSORBOARD_DIR) == (scalars, images)


class Killed(Exception):
    """The process dying after a step (no checkpoint, no stop handling)."""


@pytest.mark.slow  # three short runs that train
def test_a_killed_and_resumed_run_leaves_the_pictures_and_events_of_an_unbroken_one(tmp_path):
    pytest.importorskip("tensorboard")
    from plantdreamer.pipeline import generate_plants
    from plantdreamer.pipeline.tensorboard_writer import TENSORBOARD_DIR
    from test_generate import photometric_guidance, small

    cfg = dict(species="mint", seed=3, steps=10, checkpoint_every=4, progress_every=3,
               tensorboard=True)  # fmt: skip
    generate_plants([small(**cfg)], tmp_path / "full", guidance=photometric_guidance(),
                    show_progress=False)  # fmt: skip

    def kill(step):
        if step == 6:
            raise Killed

    with pytest.raises(Killed):
        generate_plants([small(**cfg)], tmp_path / "cut", guidance=photometric_guidance(),
                        show_progress=False, on_step=kill)  # fmt: skip
    assert (tmp_path / "cut" / "progress" / "step_000006.png").is_file()  # made before the kill
    generate_plants(None, tmp_path / "cut", guidance=photometric_guidance(), resume=True,
                    show_progress=False)  # fmt: skip
    full, cut = tmp_path / "full", tmp_path / "cut"
    frames = sorted(p.name for p in (full / "progress").iterdir())
    assert frames == [f"step_{s:06d}.png" for s in (3, 6, 9, 10)]
    for name in ("progress.png", "loss.png", *(f"progress/{f}" for f in frames)):
        assert (full / name).read_bytes() == (cut / name).read_bytes(), name
    scalars, images = read_events(full / TENSORBOARD_DIR)
    assert [s for s, _ in scalars["loss"]] == list(range(10)) and sorted(images) == [2, 5, 8, 9]
    assert read_events(cut / TENSORBOARD_DIR) == (scalars, images)
