"""``render`` deletes only the files it can prove it wrote, checks its cameras before it
writes anything, and writes each view as it is made.

A ``rendered_views.json`` naming a user's file (or a path outside ``--out``) deletes
nothing; an earlier render's own file, recorded with its digest, goes with
``--overwrite``. A camera the rasterizer would refuse (a focal length of 1e-300 or 1e308)
is refused before the folder is made. The views are on disk as they are rendered: when
view k is rendered, views 0..k-1 are already written (memory bounded by one view and the
turntable's frames, whatever --eval-views is).
"""

import json

import numpy as np
import pytest

from cli_run import one_error, run
from plantdreamer.io import write_splat_ply
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.model.init import init_gaussians


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    d = tmp_path_factory.mktemp("model")
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(200, 3)).astype(np.float32) * 0.5
    write_splat_ply(d / "model.ply", init_gaussians(pts, None, 0.9))
    return d / "model.ply"


def cameras(folder, names, focal=20.0):
    folder.mkdir(parents=True, exist_ok=True)
    frames = [{"file_path": name, "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3],
               [0, 0, 0, 1]], "w": 16, "h": 16} for name in names]  # fmt: skip
    (folder / "transforms.json").write_text(json.dumps({"fl_x": focal, "frames": frames}))
    return folder / "transforms.json"


def test_a_record_naming_a_users_file_deletes_nothing(model, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "holiday.png").write_bytes(b"my holiday")
    (tmp_path / "outside.png").write_bytes(b"mine too")
    forged = {"files": ["holiday.png", "../outside.png"],
              "sha256": {"holiday.png": "0" * 64, "../outside.png": "0" * 64}}  # fmt: skip
    (out / "rendered_views.json").write_text(json.dumps(forged))
    result = run("render", model, "--transforms", cameras(tmp_path / "a", ["a.png"]), "--out",
                 out, "--overwrite")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert (out / "holiday.png").read_bytes() == b"my holiday"
    assert (tmp_path / "outside.png").read_bytes() == b"mine too"
    assert sorted(p.name for p in out.iterdir()) == ["a.png", "holiday.png", "rendered_views.json"]


def test_an_earlier_renders_own_files_go_and_changed_ones_stay(model, tmp_path):
    out = tmp_path / "out"
    two = cameras(tmp_path / "two", ["a.png", "b.png", "c.png"])
    assert run("render", model, "--transforms", two, "--out", out).exit_code == 0
    (out / "c.png").write_bytes(b"changed by the user since")
    one = cameras(tmp_path / "one", ["a.png"])
    result = run("render", model, "--transforms", one, "--out", out, "--overwrite")
    assert result.exit_code == 0, result.output
    assert not (out / "b.png").exists()  # the earlier render's own view, proven
    assert (out / "c.png").read_bytes() == b"changed by the user since"


@pytest.mark.parametrize("focal", [1e-300, 1e308])
def test_cameras_are_checked_before_anything_is_written(model, tmp_path, focal):
    out = tmp_path / "new" / "out"
    result = run("render", model, "--transforms", cameras(tmp_path / "c", ["a.png"], focal),
                 "--out", out)  # fmt: skip
    one_error(result, "camera 0")
    assert not (tmp_path / "new").exists()


def files_at_each_render(monkeypatch, folder):
    """How many view PNGs ``folder`` holds each time a view is rendered."""
    seen = []
    original = GaussianModel.render

    def counting(self, *args, **kwargs):
        seen.append(len(list(folder.glob("view_*.png"))))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(GaussianModel, "render", counting)
    return seen


def test_render_writes_each_view_before_the_next(model, tmp_path, monkeypatch):
    out = tmp_path / "out"
    seen = files_at_each_render(monkeypatch, out)
    result = run("render", model, "--out", out, "--eval-views", 6, "--resolution", 16,
                 "--turntable", "gif")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert seen == [0, 1, 2, 3, 4, 5]
    assert (out / "turntable.gif").is_file()


def test_generate_writes_each_view_before_the_next(tmp_path, monkeypatch):
    out = tmp_path / "run"
    seen = files_at_each_render(monkeypatch, out / "renders")
    result = run("generate", "--species", "bean", "--guidance", "none", "--points", 300,
                 "--steps", 0, "--eval-views", 4, "--resolution", 16, "--turntable", "none",
                 "--quiet", "--out", out)  # fmt: skip
    assert result.exit_code == 0, result.output
    assert seen[-4:] == [0, 1, 2, 3]


def test_only_the_turntables_frames_are_kept(tmp_path):
    from plantdreamer.pipeline.outputs import StreamedViews, turntable_picks

    views = StreamedViews(tmp_path, 50, 4, "gif")
    for i in range(50):
        views.add(i, np.full((2, 2, 3), i, dtype=np.uint8))
    assert len(views.kept) == 4 and [int(f[0, 0, 0]) for f in views.kept] == [0, 12, 25, 37]
    assert turntable_picks(50, 4) == [0, 12, 25, 37] and views.written == 50
    assert not StreamedViews(tmp_path, 50, 4, "none").picks
