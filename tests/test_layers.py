"""The package's modules import one way (the Python side of
``crates/splat_core/tests/raster_layers.rs``).

Every ``import`` of every module under ``python/plantdreamer`` is read with ``ast`` (module
level, inside functions and under ``if TYPE_CHECKING``) and checked against ``LAYERS``:

- a module imports only from its own layer or the layers below it;
- the modules form no import cycle, and neither do the areas (a subpackage, or a top-level
  module), so two subpackages never import each other even through different modules.

A new module joins the layer of its area; a new area is added to ``LAYERS`` where its
imports put it. ``EXCEPTIONS`` lists the deliberate upward imports, each with its reason.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "plantdreamer"

# Lowest first. An area is a subpackage (``pipeline``) or a top-level module (``io``);
# ``plantdreamer`` is the package's ``__init__`` (its public names), ``_core`` the native
# module.
LAYERS: list[tuple[str, set[str]]] = [
    ("native", {"_core"}),
    (
        "foundation: errors, files, settings, seeds, process state",
        {"errors", "integers", "atomic", "checkpoint_io", "versions", "output_folder", "digests"}
        | {"text_escape", "temporaries", "output_locks", "output_names", "output_survey"}
        | {"source_date"}
        | {"settings", "seeds", "thread_policy", "stop_signals", "devices"},
    ),
    (
        "the model and its I/O: clouds, Gaussians, cameras, PLY, the rasterizer, plants",
        {"plantdreamer", "cloud", "gaussians", "cameras", "labels", "io", "pointcloud"}
        | {"prepare", "framing", "rasterizer", "turntable", "lsystem", "camera_rigs"},
    ),
    (
        "what reads or writes the model: guidance, scoring, traits, label files, viewer, views",
        {"guidance", "eval", "traits", "exports", "viewer", "views"},
    ),
    (
        "generation and training: the pipeline, LoRA, the torch Dataset",
        {"pipeline", "lora", "data"},
    ),
    ("scenes of finished plants, rendered together", {"scenes"}),
    ("drivers of many runs: datasets on Ray, the known answer", {"dataset", "known_answer"}),
    ("the Python API and the command line", {"api", "install_check", "cli", "__main__"}),
]

# Inside ``pipeline``, lowest first, the same rule: a module imports only from its own
# part or the parts below it (the package's ``__init__`` is with the runs).
PIPELINE_LAYERS: list[tuple[str, set[str]]] = [
    ("what watches a trainer", {"observer"}),
    (
        "a plant's parts: the model wing, ground truth, outputs and progress",
        {"model", "model.gaussian_model", "model.render", "model.sampler", "model.source"}
        | {"model.init", "model.culling", "model.density", "model.density_ops"}
        | {"truth", "truth.ground_truth", "truth.label_channels", "truth.label_pieces"}
        | {"truth.dataset_export", "outputs", "progress", "progress_pictures", "log_plot"}
        | {"tensorboard_writer", "run_observers", "settings.train_config"},
    ),
    (
        "the settings wing: the config, presets, the resolved run, what a run writes",
        {"settings", "settings.config", "settings.presets", "settings.resolved"}
        | {"settings.group_settings", "settings.runtime", "settings.requested"}
        | {"state.run_outputs"},
    ),
    (
        "the run's state wing: its state, checkpoints and noise; the record",
        {"state", "state.run_state", "state.checkpoint", "state.group_noise", "rerender"}
        | {"runs.record"},
    ),
    ("a plant of a trainer, the step's options", {"step.plant", "step.options"}),
    ("the training step: a plant's update, the step's order", {"step.update", "step.schedule"}),
    ("the step's package and the loop around the steps", {"step", "trainer", "export"}),
    (
        "the run's lifecycle: where plants live, what is done with each, a part's sequence",
        {"runs.layout", "runs.plan", "runs.start", "runs.results", "runs.sequence"},
    ),
    ("the one entry of runs of one plant or many", {"pipeline", "runs", "runs.entry"}),
]

# (importing module, imported module): why the upward import is deliberate. Empty today;
# an entry needs a reason a reviewer accepts, not a workaround for a cycle.
EXCEPTIONS: dict[tuple[str, str], str] = {}


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def read_modules(root: Path = PACKAGE) -> dict[str, ast.Module]:
    return {
        module_name(p, root): ast.parse(p.read_text(), str(p)) for p in sorted(root.rglob("*.py"))
    }


def imported(name: str, tree: ast.Module, known: Iterable[str]) -> set[str]:
    """The package's modules ``name`` imports, wherever in the file the import is. ``from
    a import b`` names module ``a.b`` when ``b`` is one, else ``a``."""
    known = set(known) | {"plantdreamer._core"}
    is_package = any(k.startswith(name + ".") for k in known)
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                here = name.split(".") if is_package else name.split(".")[:-1]
                here = here[: len(here) - (node.level - 1)]
                base = ".".join([*here, base] if base else here)
            targets = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names
            ]
        else:
            continue
        for target in targets:
            while target and target not in known:  # plantdreamer.x.Name -> plantdreamer.x
                target = target.rpartition(".")[0]
            if target.startswith("plantdreamer") and target != name:
                out.add(target)
    return out


def import_graph(modules: dict[str, ast.Module]) -> dict[str, set[str]]:
    return {name: imported(name, tree, modules) for name, tree in modules.items()}


def area(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def layer_of(module: str) -> int:
    for rank, (_, areas) in enumerate(LAYERS):
        if area(module) in areas:
            return rank
    raise KeyError(f"{module}: its area {area(module)!r} is in no layer of LAYERS")


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    bad = []
    for module, targets in sorted(graph.items()):
        for target in sorted(targets):
            if layer_of(target) > layer_of(module) and (module, target) not in EXCEPTIONS:
                low, high = LAYERS[layer_of(module)][0], LAYERS[layer_of(target)][0]
                bad.append(f"{module} -> {target} ({low!r} imports {high!r})")
    return bad


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of ``graph`` (its nodes in order, the first repeated at the end), if any."""
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt) :], nxt]
            if nxt not in state and (cycle := visit(nxt, path)):
                return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node, [])):
            return cycle
    return None


def area_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    for module, targets in graph.items():
        mine = area(module)
        out.setdefault(mine, set()).update(
            area(t) for t in targets if area(t) != mine and (module, t) not in EXCEPTIONS
        )
    return out


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph(read_modules())


def test_every_area_has_a_layer(graph: dict[str, set[str]]) -> None:
    assert len(graph) > 140, f"read {len(graph)} modules"
    for module in graph:
        layer_of(module)
    listed = set().union(*(areas for _, areas in LAYERS))
    present = {area(m) for m in graph} | {"_core"}
    assert listed == present, f"LAYERS names areas that do not exist: {listed - present}"


def test_imports_run_downward(graph: dict[str, set[str]]) -> None:
    # The reader sees imports at every place they are written (sanity of the reader).
    assert "plantdreamer.guidance.config" in graph["plantdreamer.pipeline.settings.config"]
    assert "plantdreamer._core" in graph["plantdreamer.io"]
    assert "plantdreamer.io" in graph["plantdreamer.pipeline.model.source"]  # inside a function
    bad = upward_imports(graph)
    assert not bad, "imports of a higher layer (move the shared name down):\n" + "\n".join(bad)


def pipeline_name(module: str) -> str:
    """``plantdreamer.pipeline.step.schedule`` -> ``step.schedule``; the package itself is
    ``pipeline``."""
    return module.removeprefix("plantdreamer.pipeline.").removeprefix("plantdreamer.")


def pipeline_layer_of(module: str) -> int:
    name = pipeline_name(module)
    for rank, (_, names) in enumerate(PIPELINE_LAYERS):
        if name in names:
            return rank
    raise KeyError(f"{module} is in no part of PIPELINE_LAYERS")


def test_the_pipeline_imports_run_downward(graph: dict[str, set[str]]) -> None:
    inside = {m for m in graph if area(m) == "pipeline"}
    listed = set().union(*(names for _, names in PIPELINE_LAYERS))
    assert listed == {pipeline_name(m) for m in inside}, "PIPELINE_LAYERS lists other modules"
    bad = [
        f"{m} -> {t}"
        for m in sorted(inside)
        for t in sorted(graph[m] & inside)
        if pipeline_layer_of(t) > pipeline_layer_of(m)
    ]
    assert not bad, "pipeline imports of a higher part:\n" + "\n".join(bad)


def test_no_import_cycle(graph: dict[str, set[str]]) -> None:
    assert find_cycle(graph) is None, f"import cycle between modules: {find_cycle(graph)}"
    areas = area_graph(graph)
    assert find_cycle(areas) is None, f"import cycle between areas: {find_cycle(areas)}"


def test_only_the_command_line_imports_the_command_line(graph: dict[str, set[str]]) -> None:
    """The API and everything else sit below ``cli/`` (the routines both front ends call
    live in ``pipeline`` and ``dataset``): only ``__main__`` and ``cli`` import it."""
    assert "plantdreamer.cli.options" in graph["plantdreamer.cli.generate"]  # the reader sees it
    importers = sorted(
        module
        for module, targets in graph.items()
        if area(module) not in ("cli", "__main__") and any(area(t) == "cli" for t in targets)
    )
    assert importers == [], f"modules importing plantdreamer.cli: {importers}"


def test_exceptions_are_still_needed(graph: dict[str, set[str]]) -> None:
    stale = [pair for pair in EXCEPTIONS if pair[1] not in graph.get(pair[0], set())]
    assert not stale, f"listed exceptions no module makes any more: {stale}"


def test_the_checker_finds_upward_imports_and_cycles(tmp_path: Path) -> None:
    pkg = tmp_path / "plantdreamer"
    (pkg / "exports").mkdir(parents=True)
    (pkg / "pipeline").mkdir()
    files = {
        "__init__.py": "",
        "errors.py": "from plantdreamer._core import PlyError\n",
        "exports/__init__.py": "",
        "exports/a.py": "def f():\n    from plantdreamer.pipeline.config import X\n",
        "exports/b.py": "from . import a\nfrom .a import f\n",
        "pipeline/__init__.py": "from plantdreamer.pipeline import config\n",
        "pipeline/config.py": (
            "from typing import TYPE_CHECKING\nfrom plantdreamer import errors\n"
            "if TYPE_CHECKING:\n    from plantdreamer.pipeline.source import S\n"
        ),
        "pipeline/source.py": "import plantdreamer.pipeline.config\n",
    }
    for name, text in files.items():
        (pkg / name).write_text(text)
    g = import_graph(read_modules(pkg))
    assert g["plantdreamer.errors"] == {"plantdreamer._core"}
    assert g["plantdreamer.exports.b"] == {"plantdreamer.exports.a"}
    assert g["plantdreamer.pipeline.config"] == {
        "plantdreamer.errors",
        "plantdreamer.pipeline.source",
    }
    assert upward_imports(g) == [
        "plantdreamer.exports.a -> plantdreamer.pipeline.config ("
        f"{LAYERS[3][0]!r} imports {LAYERS[4][0]!r})"
    ]
    cycle = find_cycle(g)
    assert cycle is not None and cycle[0] == cycle[-1]
    assert set(cycle) == {
        "plantdreamer.pipeline.config",
        "plantdreamer.pipeline.source",
    }
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None
    assert find_cycle({"a": {"a"}}) == ["a", "a"]
