"""Ray's token, however it is given (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH``,
``~/.ray/auth_token``): present and private, checked before Ray starts or is joined, or one
error line; and Ray's own failures to start or join reach a user as one line, a Python
caller as a ``PlantDreamerError`` without Ray's traceback. No Ray starts here."""

from __future__ import annotations

import os

import pytest
from click.testing import CliRunner

import plantdreamer
from plantdreamer.cli import main
from plantdreamer.dataset import engine
from plantdreamer.dataset.ray_token import check_token

ray = pytest.importorskip("ray")
FAST = ["--species", "bean", "--guidance", "none", "--steps", "1", "--allow-empty-split"]


@pytest.fixture(autouse=True)
def own_home(tmp_path, monkeypatch):
    """A home of the test's own (the default token file is made there), no token given."""
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    for name in ("RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH", "RAY_AUTH_MODE"):
        monkeypatch.delenv(name, raising=False)
    return tmp_path / "home"


def token_file(folder, mode, text="0123abcd"):
    path = folder / "token"
    path.write_text(text)
    path.chmod(mode)
    return path


def bad_tokens(tmp_path):
    """(environment, the refusal's words) for each way a token can be missing or open."""
    folder = tmp_path / "shared"
    folder.mkdir()
    (folder / "dir").mkdir()
    return [
        ({"RAY_AUTH_TOKEN_PATH": str(folder / "missing")}, "no such file"),
        ({"RAY_AUTH_TOKEN_PATH": str(token_file(folder, 0o644))}, "other users can read or change"),
        ({"RAY_AUTH_TOKEN_PATH": str(folder / "dir")}, "not a file"),
        ({"RAY_AUTH_TOKEN_PATH": ""}, "RAY_AUTH_TOKEN_PATH is set but empty"),
        ({"RAY_AUTH_TOKEN": "  "}, "RAY_AUTH_TOKEN is set but empty"),
    ]


@pytest.mark.parametrize("case", range(5))
@pytest.mark.parametrize("address", ["local", "127.0.0.1:1"])
def test_a_missing_or_readable_token_is_refused_before_ray_starts_or_is_joined(
    tmp_path, monkeypatch, case, address
):
    env, words = bad_tokens(tmp_path)[case]
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    monkeypatch.setattr(ray, "init", lambda *a, **k: pytest.fail("Ray started"))
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["dataset", *FAST, "--address", address, "--out", str(out)])
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 1 and len(errors) == 1, result.output
    assert words in errors[0] and "Traceback" not in result.output, result.output
    assert not (out / "plants").exists() and not (out / "dataset.json").exists()


def test_the_token_file_named_is_refused_as_it_is_never_changed(tmp_path, monkeypatch):
    for mode in (0o640, 0o604, 0o620, 0o602):
        path = token_file(tmp_path, mode)
        monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(path))
        with pytest.raises(plantdreamer.InputError, match=f"mode {mode:o}"):
            check_token(local=True)
        assert path.stat().st_mode & 0o777 == mode and path.read_text() == "0123abcd"
    empty = token_file(tmp_path, 0o600, text="\n")
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(empty))
    with pytest.raises(plantdreamer.InputError, match="the file is empty"):
        check_token(local=False)


@pytest.mark.skipif(os.getuid() != 0, reason="giving a file to another user needs root")
def test_a_token_file_of_another_user_is_refused(tmp_path, monkeypatch):
    path = token_file(tmp_path, 0o600)
    os.chown(path, 4242, -1)
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(path))
    with pytest.raises(plantdreamer.InputError, match="belongs to another user"):
        check_token(local=True)


def test_a_private_token_passes_and_no_default_file_is_made(tmp_path, monkeypatch, own_home):
    path = token_file(tmp_path, 0o600)
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(path))
    check_token(local=True)
    monkeypatch.delenv("RAY_AUTH_TOKEN_PATH")
    monkeypatch.setenv("RAY_AUTH_TOKEN", "0123abcd")
    check_token(local=True)
    assert not own_home.exists()  # a token given: the default file is none of ours to make
    monkeypatch.delenv("RAY_AUTH_TOKEN")
    check_token(local=False)  # joining makes no token file either
    assert not own_home.exists()
    check_token(local=True)  # a local Ray without one: made, private
    made = own_home / ".ray" / "auth_token"
    assert made.stat().st_mode & 0o777 == 0o600 and len(made.read_text()) == 64


def test_rays_own_start_failure_is_one_line(monkeypatch):
    def init(*args, **kwargs):
        raise RuntimeError("Failed to start the GCS server.\n  File ray/_private/node.py ...")

    monkeypatch.setenv("RAY_AUTH_TOKEN", "0123abcd")
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", init)
    monkeypatch.setattr(ray, "shutdown", lambda: None)
    with pytest.raises(engine.RayStartError) as failed:
        engine.connect("local", 1)
    message = str(failed.value)
    assert message == "the local Ray did not start (RuntimeError: Failed to start the GCS server.)"
    assert failed.value.__cause__ is None and failed.value.__suppress_context__


def test_a_cluster_that_does_not_answer_is_one_error_for_a_python_caller(tmp_path):
    with pytest.raises(plantdreamer.PlantDreamerError) as failed:
        plantdreamer.make_dataset(tmp_path, species="bean", guidance="none", steps=1,
                                  address="127.0.0.1:1", allow_empty_split=True)  # fmt: skip
    message = str(failed.value)
    assert message.startswith("cannot join the Ray cluster at 127.0.0.1:1: nothing answers")
    assert "\n" not in message and failed.value.__cause__ is None
    assert not (tmp_path / "plants").exists()
