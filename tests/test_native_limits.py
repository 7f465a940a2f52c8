"""Sizes that reach the native core: every integer argument of every entry point of
``plantdreamer._core`` (see ``_core.pyi``) is checked with a clear InputError, image sizes
whose buffers cannot fit are refused before allocating, kNN cost is bounded, and the
thread-pool cache does not grow with every distinct ``threads=`` value."""

from __future__ import annotations

import inspect
import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from plantdreamer import _core
from plantdreamer.errors import InputError

# Every function of the native module, with its integer arguments and their minimum.
INT_ARGS: dict[str, list[tuple[str, int]]] = {
    "check_ply_vertex": [],
    "downsample_to_count": [("target", 1), ("threads", 1)],
    "eval_sh": [("degree", 0)],
    "group_coverage": [("camera", 0), ("tile_size", 0), ("threads", 1)],
    "info": [],
    "knn": [("k", 1), ("threads", 1)],
    "knn_mean_distance": [("k", 1), ("threads", 1)],
    "large_gaussian_mask": [],
    "raster_defaults": [],
    "rasterize_backward_many": [("threads", 1)],
    # A scene's own integers (width, height, sh_degree): SCENE_INT_ARGS.
    "rasterize_forward_many": [("tile_size", 0), ("threads", 1)],
    "read_ply_vertex": [],
    "remove_statistical_outliers": [("nb_neighbors", 1), ("threads", 1)],
    "voxel_downsample": [("threads", 1)],
    "write_ply_vertex": [],
}

# The integers of a scene of rasterize_forward_many, each a failure of that scene alone.
SCENE_INT_ARGS = [("width", 1), ("height", 1), ("sh_degree", 0)]

_RNG = np.random.default_rng(0)
_PTS = _RNG.random((60, 3)).astype(np.float32)


def _scene() -> dict:
    """One scene of rasterize_forward_many (its dict's keys)."""
    n = 8
    return {
        "means": (_RNG.random((n, 3)) - 0.5).astype(np.float32),
        "quats": np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
        "scales": np.full((n, 3), 0.05, np.float32),
        "opacities": np.full(n, 0.8, np.float32),
        "colors": _RNG.random((n, 4, 3)).astype(np.float32),
        "viewmats": np.array(
            [[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]]], np.float32
        ),
        "Ks": np.array([[[20, 0, 8], [0, 20, 8], [0, 0, 1]]], np.float32),
        "width": 16,
        "height": 16,
        "sh_degree": 1,
    }


def _call(name: str, tmp_path, **override):
    """A valid call of `name`, with `override` replacing some arguments."""
    if name == "rasterize_backward_many":
        (out,) = _core.rasterize_forward_many([_scene()])
        args = {
            "states": [out["state"]],
            "v_renders": [np.ones_like(out["render"])],
            "v_alphas": [np.ones_like(out["alpha"])],
            "threads": None,
        }
    elif name == "rasterize_forward_many":
        args = {"scenes": [_scene()], "tile_size": 16, "threads": None}
    elif name == "group_coverage":
        (out,) = _core.rasterize_forward_many([_scene()])
        args = {
            "state": out["state"],
            "groups": np.zeros(8, np.int32),
            "labels": np.zeros((16, 16), np.int32),
            "group_labels": np.zeros(1, np.int32),
            "alpha_threshold": 0.5,
            "camera": 0,
            "tile_size": 16,
            "threads": None,
        }
    else:
        args = {
            "downsample_to_count": {"points": _PTS, "target": 20, "threads": None},
            "eval_sh": {
                "degree": 1,
                "coeffs": np.ones((5, 4, 3), np.float32),
                "dirs": np.ones((5, 3), np.float32),
            },
            "info": {},
            "knn": {"points": _PTS, "k": 4, "threads": None},
            "knn_mean_distance": {"points": _PTS, "k": 4, "threads": None},
            "large_gaussian_mask": {"log_scales": np.zeros((4, 3), np.float32)},
            "raster_defaults": {},
            "read_ply_vertex": {"path": str(tmp_path / "ok.ply")},
            "check_ply_vertex": {"path": str(tmp_path / "ok.ply")},
            "remove_statistical_outliers": {
                "points": _PTS,
                "nb_neighbors": 5,
                "std_ratio": 2.0,
                "threads": None,
            },
            "voxel_downsample": {"points": _PTS, "voxel_size": 0.1, "threads": None},
            "write_ply_vertex": {
                "path": str(tmp_path / "ok.ply"),
                "fields": [(["x", "y", "z"], _PTS)],
            },
        }[name]
    args.update(override)
    return getattr(_core, name)(**args)


def test_the_table_covers_every_native_function():
    functions = {
        name
        for name in _core.__all__
        if inspect.isroutine(getattr(_core, name)) and not name.startswith("_")
    }
    assert functions == set(INT_ARGS)


@pytest.mark.parametrize("name", sorted(INT_ARGS))
def test_each_base_call_is_valid(tmp_path, name):
    _core.write_ply_vertex(str(tmp_path / "ok.ply"), [(["x", "y", "z"], _PTS)])
    _call(name, tmp_path)


BAD_VALUES = [-1, -(2**63), 2**63, 2**70, 2.5, "3", [1]]
CASES = [(name, arg, low) for name, args in INT_ARGS.items() for arg, low in args]


@pytest.mark.parametrize(("name", "arg", "low"), CASES)
@pytest.mark.parametrize("bad", [*BAD_VALUES, "below"], ids=repr)
def test_bad_integers_are_input_errors(tmp_path, name, arg, low, bad):
    value = low - 1 if bad == "below" else bad
    with pytest.raises(InputError, match=arg):
        _call(name, tmp_path, **{arg: value})


@pytest.mark.parametrize(("arg", "low"), SCENE_INT_ARGS)
@pytest.mark.parametrize("bad", [*BAD_VALUES, "below"], ids=repr)
def test_a_batched_scenes_bad_integers_are_its_own_input_error(arg, low, bad):
    """A scene of a batch with a bad integer fails alone: its entry is the InputError."""
    scene = _scene()
    good = dict(scene)
    scene[arg] = low - 1 if bad == "below" else bad
    results = _core.rasterize_forward_many([good, scene])
    assert isinstance(results[0], dict)
    assert isinstance(results[1], InputError) and arg in str(results[1])


@pytest.mark.parametrize("size", [(2**31, 2**31), (2**32 - 1, 2**32 - 1), (100_000, 100_000)])
def test_image_sizes_whose_buffers_cannot_fit_are_refused(tmp_path, size):
    w, h = size
    (result,) = _call(
        "rasterize_forward_many", tmp_path, scenes=[_scene() | {"width": w, "height": h}]
    )
    assert isinstance(result, InputError)
    assert re.search(rf"{w} x {h} pixels.*would need [0-9.]+ [KMGTP]iB", str(result))


def test_rasterization_refuses_huge_images_before_allocating():
    torch = pytest.importorskip("torch")
    from plantdreamer import rasterization

    s = _scene()
    t = {k: torch.from_numpy(s[k]) for k in ("means", "quats", "scales", "opacities", "viewmats")}
    with pytest.raises(InputError, match="pixels"):
        rasterization(
            t["means"],
            t["quats"],
            t["scales"],
            t["opacities"],
            torch.ones(8, 3),
            t["viewmats"],
            torch.from_numpy(s["Ks"]),
            2**31,
            2**31,
        )


def test_too_many_threads_is_an_input_error_naming_the_limit(tmp_path):
    with pytest.raises(InputError, match=r"threads must be in 1\.\.=\d+ \(4 x the"):
        _call("knn", tmp_path, threads=10**6)


# --- kNN: k close to N is exact and bounded; n x k beyond the limit is refused ---------


def test_knn_with_k_close_to_n_matches_brute_force():
    p = _RNG.random((700, 3)).astype(np.float32)
    k = 699
    idx, d = _core.knn(p, k)
    full = np.sqrt(((p[:, None, :].astype(np.float64) - p[None]) ** 2).sum(-1))
    np.fill_diagonal(full, np.inf)
    order = np.argsort(full, axis=1, kind="stable")[:, :k]
    np.testing.assert_array_equal(idx, order)
    np.testing.assert_array_equal(d, np.take_along_axis(full, order, 1).astype(np.float32))


def test_knn_output_beyond_the_pair_limit_is_refused_before_allocating():
    p = _RNG.random((70_000, 3)).astype(np.float32)
    with pytest.raises(InputError, match=r"pairs, more than the 2147483648.*GiB"):
        _core.knn(p, 40_000)
    with pytest.raises(InputError, match="pairs"):
        _core.remove_statistical_outliers(p, 40_000, 2.0)


# --- the thread-pool cache is bounded ------------------------------------------------

_POOL_CHURN = """
    import os, time
    import numpy as np
    from plantdreamer import _core

    def pool_threads():
        n = 0
        for t in os.listdir("/proc/self/task"):
            try:
                with open(f"/proc/self/task/{t}/comm") as f:
                    n += f.read().startswith("plantdreamer")
            except FileNotFoundError:
                pass
        return n

    top = TOP
    p = np.random.default_rng(0).random((200, 3)).astype(np.float32)
    for _ in range(3):
        for t in range(1, top + 1):
            _core.knn(p, 3, threads=t)
    # Dropped pools end their threads asynchronously: wait for them (up to 30 s).
    deadline = time.monotonic() + 30
    while pool_threads() > BOUND and time.monotonic() < deadline:
        time.sleep(0.05)
    print(pool_threads())
"""


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="needs Linux /proc")
def test_distinct_thread_counts_do_not_accumulate_threads():
    top = min(_core.info()["max_threads"], 16)  # sizes 1..top; 16 keeps big machines quick
    kept = sum(range(top, top - 4, -1))  # the four most recent pools
    code = textwrap.dedent(_POOL_CHURN).replace("TOP", str(top)).replace("BOUND", str(kept))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    # Without a bound every size 1..top would stay alive: top * (top + 1) / 2 threads
    # (36 for top = 8, against at most 26 kept).
    assert int(out.stdout) <= kept


def test_render_refuses_a_resolution_whose_buffers_cannot_fit(tmp_path):
    """`render --resolution 100000` was killed by the OOM killer at 23.9 GB; now the core
    refuses it before allocating (run under a 16 GiB address-space limit, so a regression
    fails fast instead of exhausting the machine)."""
    import resource

    from plantdreamer.gaussians import Gaussians
    from plantdreamer.io import write_splat_ply

    n = 10
    write_splat_ply(
        tmp_path / "g.ply",
        Gaussians(
            means=_RNG.random((n, 3)).astype(np.float32),
            quats=np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
            log_scales=np.full((n, 3), -3, np.float32),
            opacity_logits=np.zeros(n, np.float32),
            sh=np.zeros((n, 1, 3), np.float32),
        ),
    )

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (16 << 30, 16 << 30))

    args = ["render", str(tmp_path / "g.ply"), "--out", str(tmp_path / "out")]
    args += ["--resolution", "100000", "--eval-views", "1"]
    out = subprocess.run(
        [sys.executable, "-m", "plantdreamer", *args],
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=limit,
    )
    assert out.returncode == 1, out.stderr
    assert "100000 x 100000 pixels" in out.stderr and "GiB" in out.stderr
    assert "Traceback" not in out.stderr + out.stdout
