"""Only what plantdreamer made is removed as a temporary, a refused claim deletes nothing,
and an output's name is known to work before the old output goes.

A user's ``.backup.20240101.tmp/`` folder or ``.notes.link`` file looks like a temporary by
name; the temporaries the program makes carry a check it verifies (``temporaries``), so
those are left whole, whatever the claim (``--overwrite``, a resume, a refusal).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from cli_run import run
from plantdreamer.cloud import PointCloud
from plantdreamer.io import write_ply
from plantdreamer.output_folder import claim_files, claim_folder
from plantdreamer.pipeline.state.run_outputs import RUN_OUTPUTS
from plantdreamer.temporaries import is_temporary, is_temporary_of, temporary_name

TINY = ["--guidance", "none", "--points", "300", "--steps", "0", "--eval-views", "1",
        "--resolution", "16", "--turntable", "none", "--quiet"]  # fmt: skip


def users_lookalikes(folder):
    """A user's folder and file named as temporaries once were; returns them."""
    backup = folder / ".backup.20240101.tmp"
    backup.mkdir(parents=True)
    (backup / "plant.ply").write_bytes(b"the user's backup")
    link = folder / ".notes.link"
    link.write_text("the user's notes")
    return backup, link


def whole(backup, link):
    return (backup / "plant.ply").read_bytes() == b"the user's backup" and (
        link.read_text() == "the user's notes"
    )


def test_only_names_the_program_made_are_temporaries():
    for name in ("plant.ply", "view_000.png", "a" * 300, "é" * 200, "staging"):
        made = temporary_name(name)
        assert is_temporary(made) and len(os.fsencode(made)) <= 255
        assert is_temporary_of(made, name)
        assert is_temporary(temporary_name(name, "link"))
    made = temporary_name("plant.ply")
    forged = made[:-12] + ("0" if made[-12] != "0" else "1") + made[-11:]  # one tag digit
    for name in (".backup.20240101.tmp", ".notes.link", ".plant.ply.k3j9x0a1.tmp.ply", forged):
        assert not is_temporary(name), name
    assert not is_temporary_of(made, "other.ply")
    assert made.endswith(".tmp.ply")  # the suffix writers pick a format from


def test_overwrite_and_resume_keep_a_users_lookalikes(tmp_path):
    out = tmp_path / "run"
    backup, link = users_lookalikes(out)
    (out / "run.json").write_text("{}")
    ours = out / temporary_name("checkpoint.pt")
    ours.write_bytes(b"a killed write")
    with claim_folder(out, owned=RUN_OUTPUTS, allow_existing=True):
        pass
    assert whole(backup, link) and not ours.exists()
    with claim_folder(out, overwrite=True, owned=RUN_OUTPUTS):
        pass
    assert whole(backup, link) and not (out / "run.json").exists()


def test_a_refused_claim_deletes_nothing(tmp_path):
    out = tmp_path / "run"
    backup, link = users_lookalikes(out)
    (out / "notes.txt").write_text("mine")
    ours = out / temporary_name("checkpoint.pt")
    ours.write_bytes(b"a killed write")
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(Exception, match="not empty"), claim_folder(out, owned=RUN_OUTPUTS):
        pass
    assert sorted(p.name for p in out.iterdir()) == before and whole(backup, link)


def test_a_users_lookalike_inside_an_output_folder_is_refused_not_removed(tmp_path):
    out = tmp_path / "run"
    (out / "renders").mkdir(parents=True)
    (out / "renders" / "view_000.png").write_bytes(b"earlier view")
    backup, link = users_lookalikes(out / "renders")
    with pytest.raises(Exception, match="does not write"):
        with claim_folder(out, overwrite=True, owned=RUN_OUTPUTS):
            pass
    assert whole(backup, link) and (out / "renders" / "view_000.png").exists()


def test_generate_overwrite_keeps_a_users_lookalikes(tmp_path):
    out = tmp_path / "run"
    assert run("generate", "--species", "bean", *TINY, "--out", out).exit_code == 0
    backup, link = users_lookalikes(out)
    result = run("generate", "--species", "bean", *TINY, "--out", out, "--overwrite")
    assert result.exit_code == 0, result.output
    assert whole(backup, link)


def test_a_yolo_link_leaves_a_users_link_named_file(tmp_path):
    from plantdreamer.exports.yolo import link_image

    source = tmp_path / "view_000.png"
    source.write_bytes(b"a view")
    target = tmp_path / "yolo" / "view_000.png"
    target.parent.mkdir()
    mine = target.with_name(".view_000.png.link")
    mine.write_text("the user's")
    link_image(source, target)
    assert target.read_bytes() == b"a view" and mine.read_text() == "the user's"
    assert sorted(p.name for p in target.parent.iterdir()) == [".view_000.png.link", target.name]


def cloud(path):
    rng = np.random.default_rng(0)
    write_ply(path, PointCloud(rng.normal(size=(50, 3)).astype(np.float32)))


def test_prepare_overwrite_of_a_long_name_replaces_it(tmp_path):
    """A 240-byte name is valid; its temporary (longer) must still work after the old
    output went."""
    cloud(tmp_path / "in.ply")
    out = tmp_path / ("p" * 236 + ".ply")
    args = ["prepare", tmp_path / "in.ply", "-o", out, "--points", 0, "--sor-neighbors", 0]
    assert run(*args).exit_code == 0
    out.write_bytes(b"the earlier output")
    result = run(*args, "--overwrite")
    assert result.exit_code == 0, result.output
    assert out.read_bytes().startswith(b"ply") and sorted(p.name for p in tmp_path.iterdir()) == [
        "in.ply",
        out.name,
    ]


def test_a_name_too_long_for_a_companion_is_refused_before_deleting(tmp_path):
    cloud(tmp_path / "in.ply")
    out = tmp_path / ("p" * 245 + ".ply")  # its .transform.json would be 260 bytes
    out.write_bytes(b"the earlier output")
    result = run("prepare", tmp_path / "in.ply", "-o", out, "--points", 0, "--overwrite")
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 1 and len(errors) == 1 and "bytes" in errors[0], result.output
    assert out.read_bytes() == b"the earlier output"
    with pytest.raises(Exception, match="NUL"), claim_files([tmp_path / "a\0b.ply"]):
        pass


def test_a_refused_claim_leaves_no_folder_of_its_own(tmp_path):
    (tmp_path / "in.ply").write_text("ply\nformat ascii 1.0\n")
    with pytest.raises(Exception, match="is an input"):
        with claim_folder(tmp_path / "new" / "out", owned=["in.ply"],
                          inputs=[tmp_path / "new" / "out" / "in.ply"]):  # fmt: skip
            pass
    with pytest.raises(RuntimeError), claim_folder(tmp_path / "new" / "out"):
        raise RuntimeError("a refusal after the claim")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.ply"]
