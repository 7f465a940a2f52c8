"""Turntables: GIF and/or MP4 (imageio-ffmpeg's ffmpeg), deterministic bytes, atomic writes,
and the --turntable option of generate and render."""

from __future__ import annotations

import json

import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np
import pytest
from click.testing import CliRunner

from plantdreamer import turntable
from plantdreamer.cli import main
from plantdreamer.errors import InputError
from plantdreamer.pipeline.outputs import write_turntables


def frames(n: int = 6, h: int = 33, w: int = 45) -> list[np.ndarray]:
    """Solid frames of distinct colours (odd sides on purpose: yuv420p needs even ones)."""
    colours = np.linspace(30, 220, n).astype(np.uint8)
    return [np.full((h, w, 3), (c, 255 - c, 128), dtype=np.uint8) for c in colours]


def read_mp4(path):
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    w, h = meta["size"]
    images = [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in reader]
    return meta, images


@pytest.mark.parametrize(
    ("fmt", "names"),
    [("gif", ["turntable.gif"]), ("mp4", ["turntable.mp4"]),
     ("both", ["turntable.gif", "turntable.mp4"]), ("none", [])],
)  # fmt: skip
def test_formats_write_their_files_only(tmp_path, fmt, names):
    written = write_turntables(tmp_path, frames(), 4, fmt)
    assert [p.name for p in written] == names
    assert sorted(p.name for p in tmp_path.iterdir()) == names  # no temporary files left


def test_mp4_holds_the_picked_frames(tmp_path):
    source = frames(8)
    (path,) = write_turntables(tmp_path, source, 4, "mp4")
    meta, images = read_mp4(path)
    assert meta["codec"] == "h264" and meta["fps"] == turntable.TURNTABLE_FPS
    assert meta["size"] == (46, 34)  # padded to even sides
    assert len(images) == 4
    for image, picked in zip(images, source[::2], strict=True):  # frames 0, 2, 4, 6
        assert image.shape == (34, 46, 3)
        # Lossy H.264 of a flat colour: within a few levels.
        np.testing.assert_allclose(image.astype(float).mean((0, 1)), picked[0, 0], atol=6)


def test_gif_holds_the_picked_frames(tmp_path):
    source = frames(8)
    (path,) = write_turntables(tmp_path, source, 4, "gif")
    images = iio.imread(path, index=None)
    assert images.shape[:3] == (4, 33, 45)
    np.testing.assert_array_equal(images[1][..., :3], source[2])


def test_mp4_bytes_are_deterministic(tmp_path):
    write_turntables(tmp_path / "a", frames(), 6, "mp4")
    write_turntables(tmp_path / "b", frames(), 6, "mp4")
    assert (tmp_path / "a/turntable.mp4").read_bytes() == (
        tmp_path / "b/turntable.mp4"
    ).read_bytes()


def test_failed_encode_leaves_the_old_file(tmp_path, monkeypatch):
    (tmp_path / "turntable.mp4").write_bytes(b"old")

    def broken(path, frames):
        path.write_bytes(b"partial")
        raise RuntimeError("encoder died")

    monkeypatch.setattr(turntable, "write_mp4", broken)
    with pytest.raises(RuntimeError):
        write_turntables(tmp_path, frames(), 4, "mp4")
    assert [p.name for p in tmp_path.iterdir()] == ["turntable.mp4"]
    assert (tmp_path / "turntable.mp4").read_bytes() == b"old"


def test_unknown_format_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="gif, mp4, both, none"):
        write_turntables(tmp_path, frames(), 4, "webm")


def test_generate_turntable_both_and_view(tmp_path, monkeypatch):
    # --view hands the finished plant to the viewer (replaced here: it would serve forever).
    viewed = []
    monkeypatch.setattr(
        "plantdreamer.viewer.server.view_files", lambda paths, **kw: viewed.extend(paths)
    )
    out = tmp_path / "run"
    result = CliRunner().invoke(
        main,
        ["generate", "--species", "kale", "--guidance", "none", "--steps", "0", "--points",
         "800", "--resolution", "32", "--eval-views", "3", "--turntable", "both", "--quiet",
         "--view", "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    _, images = read_mp4(out / "turntable.mp4")
    assert len(images) == 3 and len(iio.imread(out / "turntable.gif", index=None)) == 3
    assert json.loads((out / "run.json").read_text())["config"]["turntable"] == "both"
    assert viewed == [str(out / "plant.ply")]
    rendered = CliRunner().invoke(
        main, ["render", str(out / "plant.ply"), "--out", str(tmp_path / "r"), "--eval-views", "2",
               "--resolution", "24", "--turntable", "mp4"],
    )  # fmt: skip
    assert rendered.exit_code == 0, rendered.output
    assert sorted(p.name for p in (tmp_path / "r").glob("turntable.*")) == ["turntable.mp4"]
