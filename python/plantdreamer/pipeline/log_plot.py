"""``loss.png``: a run's log (the rows of ``log.csv``) drawn by matplotlib, one panel per
figure the log holds, over the same steps:

- ``loss``: each step's loss, faint, and its running mean;
- ``timestep``: the diffusion timestep the plant's sample drew at each step (its
  ``timesteps`` cell), between the schedule's bounds ``t_min`` and ``t_max``;
- ``gradient norm``: the guidance's gradient norm (``grad_norm``) and its running mean.

A panel whose column the log lacks is left out (a photometric fit logs only its loss), and
a run with no loss at all (no guidance) has no plot. The running mean is trailing: the mean
of each step and the ``window - 1`` before it (fewer at the start), with a window of a 50th
of the steps but at least ``RUNNING_MIN``, so a short run has one too. The same rows give
the same bytes: nothing in the file depends on the time or the matplotlib that drew it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer import atomic

LOSS_PLOT = "loss.png"
RUNNING_MIN = 10  # steps in the running mean, at least
RUNNING_SHARE = 50  # ... and a 50th of the steps
_COLOURS = {"loss": "tab:green", "timestep": "tab:blue", "gradient norm": "tab:purple"}


def running_mean(values: np.ndarray, window: int) -> np.ndarray:
    """The trailing mean of each value and the ``window - 1`` before it (all there are at
    the start): as long as ``values``."""
    values = np.asarray(values, np.float64)
    sums = np.concatenate([[0.0], np.cumsum(values)])
    ends = np.arange(1, len(values) + 1)
    starts = np.maximum(0, ends - window)
    return (sums[ends] - sums[starts]) / (ends - starts)


def running_window(count: int) -> int:
    """Steps in the running mean of ``count`` logged steps."""
    return max(RUNNING_MIN, count // RUNNING_SHARE)


def log_panels(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, np.ndarray]]:
    """The series of each panel, by panel name: ``step`` and ``value`` (and for the
    timestep ``low`` and ``high``, the schedule's bounds), from the rows that hold them."""
    from plantdreamer.pipeline.outputs import read_samples_cell

    def column(name: str) -> tuple[np.ndarray, np.ndarray]:
        found = [(r["step"], r[name]) for r in rows if _number(r.get(name)) is not None]
        steps = np.array([s for s, _ in found], np.float64)
        return steps, np.array([_number(v) for _, v in found], np.float64)

    panels: dict[str, dict[str, np.ndarray]] = {}
    for panel, name in (("loss", "loss"), ("gradient norm", "grad_norm")):
        steps, values = column(name)
        if len(steps):
            panels[panel] = {"step": steps, "value": values}
    draws = [  # the plant's own sample (a group's ``timestep`` is the batch's mean)
        (r["step"], t, r.get("t_min"), r.get("t_max"))
        for r in rows
        if isinstance(r.get("timesteps"), str)
        for t in read_samples_cell(r["timesteps"])
    ]
    if draws:
        panels["timestep"] = {
            "step": np.array([d[0] for d in draws], np.float64),
            "value": np.array([d[1] for d in draws], np.float64),
            "low": np.array([_or_nan(d[2]) for d in draws], np.float64),
            "high": np.array([_or_nan(d[3]) for d in draws], np.float64),
        }
    return {name: panels[name] for name in _COLOURS if name in panels}


def loss_figure(rows: Sequence[dict[str, Any]]) -> Any:
    """The matplotlib ``Figure`` of ``loss.png`` (its panels in the module's order), or None
    when the rows hold no loss."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    panels = log_panels(rows)
    if "loss" not in panels:
        return None
    figure = Figure(figsize=(5, 0.7 + 2.3 * len(panels)), dpi=100)
    axes = figure.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    last = max(float(p["step"].max()) for p in panels.values())
    for ax, (name, series) in zip(axes, panels.items(), strict=True):
        colour = _COLOURS[name]
        steps, values = series["step"], series["value"]
        if name == "timestep":
            ax.fill_between(steps, series["low"], series["high"], step="mid", color=colour,
                            alpha=0.12, lw=0, label="schedule's bounds")  # fmt: skip
            ax.plot(steps, values, ".", ms=2.5, color=colour, label="drawn")
        else:
            ax.plot(steps, values, lw=0.6, alpha=0.4, color=colour, label=name)
            if len(values) >= 2:
                window = running_window(len(values))
                ax.plot(steps, running_mean(values, window), lw=1.5, color=colour,
                        label=f"mean of {window} steps")  # fmt: skip
            if np.all(values > 0) and values.max() / values.min() > 100:
                ax.set_yscale("log")
        ax.set_ylabel(name)
        ax.legend(loc="upper right", frameon=False, fontsize="small")
    axes[-1].set_xlabel("step")
    axes[-1].set_xlim(0, max(1.0, np.ceil(last + 1)))
    height = figure.get_figheight()  # margins in inches, whatever the panels (tight_layout: 2x)
    figure.subplots_adjust(left=0.16, right=0.97, bottom=0.5 / height, top=1 - 0.15 / height,
                           hspace=0.12)  # fmt: skip
    return figure


def write_loss_plot(path: Path, rows: Sequence[dict[str, Any]]) -> bool:
    """Writes ``loss.png`` of ``rows`` (atomically); False, writing nothing, when they hold
    no loss."""
    figure = loss_figure(rows)
    if figure is None:
        return False
    # No "Software" entry: the same rows give the same bytes whatever matplotlib wrote them.
    atomic.atomic_write(
        path, lambda tmp: figure.savefig(tmp, format="png", metadata={"Software": None})
    )
    return True


def _number(value: Any) -> float | None:
    """A log cell as a finite number, else None (absent, empty, NaN: not logged)."""
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if np.isfinite(number) else None


def _or_nan(value: Any) -> float:
    number = _number(value)
    return np.nan if number is None else number
