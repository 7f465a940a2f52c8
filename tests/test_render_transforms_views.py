"""``render --transforms`` writes one file per camera, with the camera it was rendered at:
per-frame intrinsics are kept in the written transforms.json, frames whose file names
collide in different folders do not overwrite each other, and sizes that are not whole
pixel counts are refused."""

import json

import numpy as np
import pytest

from cli_run import run
from plantdreamer.io import write_splat_ply
from plantdreamer.pipeline.model.init import init_gaussians


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    d = tmp_path_factory.mktemp("model")
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(300, 3)).astype(np.float32) * 0.5
    gaussians = init_gaussians(pts, rng.random((300, 3)).astype(np.float32), 0.9)
    gaussians.labels = np.stack([np.ones(300), np.arange(300) % 3], axis=1).astype(np.int32)
    write_splat_ply(d / "model.ply", gaussians)
    return d / "model.ply"


def pose(distance):
    c2w = np.eye(4)
    c2w[2, 3] = distance  # looking down -z at the origin (OpenGL)
    return c2w.tolist()


def write_transforms(folder, frames, **top):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "transforms.json").write_text(json.dumps({**top, "frames": frames}))
    return folder / "transforms.json"


def test_frames_with_the_same_file_name_in_two_folders_are_both_written(model, tmp_path):
    frames = [
        {"file_path": f"cam{i}/0001.png", "transform_matrix": pose(3 + i), "w": 16, "h": 16}
        for i in (0, 1)
    ]
    cams = write_transforms(tmp_path / "cams", frames, fl_x=20.0)
    out = tmp_path / "out"
    result = run("render", model, "--transforms", cams, "--out", out)
    assert result.exit_code == 0, result.output
    assert "wrote 2 views" in result.output
    written = sorted(str(p.relative_to(out)) for p in out.rglob("*.png"))
    assert written == ["cam0/0001.png", "cam1/0001.png"]
    a, b = ((out / w).read_bytes() for w in written)
    assert a != b  # two cameras, two pictures


def test_per_frame_intrinsics_are_kept_in_the_written_transforms(model, tmp_path):
    frames = [
        {"file_path": "a", "transform_matrix": pose(4), "fl_x": 20.0, "cx": 8.0},
        {"file_path": "b", "transform_matrix": pose(4), "fl_x": 30.0, "fl_y": 25.0, "cx": 7.0,
         "w": 24, "h": 20},
    ]  # fmt: skip
    cams = write_transforms(tmp_path / "cams", frames, w=16, h=16)
    out = tmp_path / "out"
    result = run("render", model, "--transforms", cams, "--labels", "--out", out)
    assert result.exit_code == 0, result.output
    from plantdreamer.eval.datasets import scan_transforms_json

    written = scan_transforms_json(out / "transforms.json")
    given = scan_transforms_json(cams, images_required=False)
    assert len(written) == 2
    for w, g in zip(written, given, strict=True):  # each render is its camera's size
        np.testing.assert_allclose(w.camera.K, g.camera.K)
        assert (w.camera.width, w.camera.height) == (g.camera.width, g.camera.height)
    assert (written[1].camera.width, written[1].camera.height) == (24, 20)


@pytest.mark.parametrize(("value", "shown"), [(32.9, "32.9"), (True, "True"), ("16", "'16'")])
def test_sizes_that_are_not_whole_pixel_counts_are_refused(model, tmp_path, value, shown):
    frames = [{"file_path": "a", "transform_matrix": pose(4), "w": value, "h": 16}]
    cams = write_transforms(tmp_path / "cams", frames, fl_x=20.0)
    result = run("render", model, "--transforms", cams, "--out", tmp_path / "out")
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 1 and len(errors) == 1, result.output
    assert "w must be a whole number of pixels" in errors[0] and shown in errors[0], errors
    assert not list(tmp_path.glob("out/**/*.png"))


def test_the_orbit_size_left_open_is_generates_on_the_cpu(model, tmp_path):
    """`render --resolution` is generate's setting: unset, generate's size on the CPU, where
    render renders (a plant folder's run.json gives the size it was made at)."""
    from PIL import Image

    from plantdreamer.pipeline.settings.train_config import AUTO_RESOLUTION

    result = run("render", model, "--eval-views", 1, "--turntable", "none", "--out", tmp_path)
    assert result.exit_code == 0, result.output
    side = AUTO_RESOLUTION["cpu"]
    assert Image.open(tmp_path / "view_000.png").size == (side, side)


def test_overwrite_with_fewer_frames_leaves_none_of_the_earlier_views(model, tmp_path):
    def frames(n):
        return [
            {"file_path": f"shot_{i}.png", "transform_matrix": pose(3 + i), "w": 8, "h": 8}
            for i in range(n)
        ]

    out = tmp_path / "out"
    (tmp_path / "out").mkdir()
    (out / "mine.png").write_bytes(b"a picture of the user's")
    for n, overwrite in ((3, ["--overwrite"]), (1, ["--overwrite"])):
        cams = write_transforms(tmp_path / f"cams{n}", frames(n), fl_x=10.0)
        result = run("render", model, "--transforms", cams, "--out", out, *overwrite)
        assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.glob("*.png")) == ["mine.png", "shot_0.png"]


def test_two_far_strays_do_not_shrink_the_rendered_subject(model, tmp_path):
    """A model with two Gaussians moved 500 sizes away renders with the subject as large
    as without them (the orbit's framing ignores strays)."""
    from PIL import Image

    from plantdreamer.io import read_splat_ply

    g = read_splat_ply(model)
    means = g.means.copy()
    means[:2] = [[500.0, 0.0, 0.0], [-300.0, 200.0, 400.0]]
    strays = tmp_path / "strays.ply"
    write_splat_ply(strays, g.moved(means, 0.0))

    def subject_pixels(ply, out):
        result = run("render", ply, "--out", out, "--eval-views", 2, "--resolution", 64,
                     "--turntable", "none", "--background", 1.0)  # fmt: skip
        assert result.exit_code == 0, result.output
        views = [np.asarray(Image.open(p).convert("L")) for p in sorted(out.glob("view_*.png"))]
        return sum(int((v < 250).sum()) for v in views)

    clean = subject_pixels(model, tmp_path / "clean")
    assert clean > 200 and 0.7 * clean <= subject_pixels(strays, tmp_path / "strays") <= 1.3 * clean
