"""Mistakes are caught before torch is imported: a mistyped species (with the closest
name), a device this machine lacks (with or without guidance, in the same words), and
every setting, from ``generate``, ``dataset`` and the API; the devices are counted
without torch (``plantdreamer.devices``)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from plantdreamer import devices
from plantdreamer.errors import InputError

NO_GPU = "no usable CUDA GPU on this machine"
# (command line, the one error line's words); run with no GPU visible.
MISTAKES = [
    (["generate", "--species", "beam"], "unknown species 'beam' (did you mean 'bean'?)"),
    (["generate", "--species", "mint-relased"], "(did you mean 'mint-released'?)"),
    (["generate", "--species", "bean", "--device", "banana"], "unknown device 'banana'"),
    (["generate", "--species", "bean", "--device", "mps"], "device 'mps' is not supported"),
    (["generate", "--species", "bean", "--device", "cuda", "--guidance", "none"], NO_GPU),
    (["generate", "--species", "bean", "--device", "cuda:1"], NO_GPU),
    (["generate", "--species", "bean", "--steps", "-3"], "must not be negative"),
    (["generate", "--species", "bean", "--points", "0"], "points must be a positive integer"),
    (["generate", "--species", "bean", "--guidance-scale", "nan"], "must be finite"),
    (["generate", "--species", "bean", "--resolution", "5"], "resolution must be in 8.."),
    (["generate", "--species", "bean", "--seeds", "3-1"], "3-1 is a reversed range"),
    (["generate", "--species", "bean", "--seeds", "0-1", "--seed", "2"], "seed or seeds"),
    (["dataset", "--species", "beam", "--out", "{tmp}/d"], "(did you mean 'bean'?)"),
    (["dataset", "--species", "bean", "--set", "device=cuda", "--guidance", "none", "--out",
      "{tmp}/d"], NO_GPU),
]  # fmt: skip

SCRIPT = """
import json, sys
from click.testing import CliRunner
from plantdreamer.cli import main
import plantdreamer
results = []
for args in json.loads(sys.argv[1]):
    result = CliRunner().invoke(main, args)
    results.append([result.exit_code, result.output])
try:
    plantdreamer.generate(sys.argv[2] + "/api", species="beam")
except plantdreamer.InputError as exc:
    results.append([1, "error: " + str(exc)])
print(json.dumps({"results": results, "torch": "torch" in sys.modules}))
"""


@pytest.mark.parametrize(("args", "words"), MISTAKES)
def test_each_mistake_is_one_error_line(tmp_path, monkeypatch, args, words):
    from click.testing import CliRunner

    from plantdreamer.cli import main

    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")
    result = CliRunner().invoke(main, [a.format(tmp=tmp_path) for a in args])
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 1 and len(errors) == 1 and words in errors[0], result.output
    assert not any(tmp_path.iterdir())  # nothing written


@pytest.mark.slow  # a process of its own: this one has imported torch long since
def test_mistakes_are_one_error_each_and_torch_is_never_imported(tmp_path):
    commands = [[a.format(tmp=tmp_path) for a in args] for args, _ in MISTAKES]
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(SCRIPT), json.dumps(commands), str(tmp_path)],
        capture_output=True, text=True, timeout=300,
        env={**__import__("os").environ, "CUDA_VISIBLE_DEVICES": ""},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.splitlines()[-1])
    expected = [words for _, words in MISTAKES] + ["(did you mean 'bean'?)"]
    for (code, output), words in zip(report["results"], expected, strict=True):
        errors = [line for line in output.splitlines() if line.startswith("error:")]
        assert code == 1 and len(errors) == 1 and words in errors[0], output
    assert report["torch"] is False
    assert not any(tmp_path.iterdir())  # nothing written


def test_cuda_without_a_gpu_is_refused_the_same_with_or_without_guidance(monkeypatch):
    from click.testing import CliRunner

    from plantdreamer.cli import main

    monkeypatch.setattr(devices, "_nvml_device_count", lambda: 0)
    lines = []
    for guidance in ("sds", "none"):
        args = ["generate", "--species", "bean", "--device", "cuda", "--guidance", guidance]
        lines.append(CliRunner().invoke(main, args).output.strip())
    assert lines[0] == lines[1] == "error: device 'cuda': no usable CUDA GPU on this machine"


@pytest.mark.parametrize(
    ("text", "parsed"),
    [("cpu", ("cpu", None)), ("cuda", ("cuda", None)), ("cuda:3", ("cuda", 3)),
     ("cpu:0", ("cpu", 0))],
)  # fmt: skip
def test_devices_are_read_as_torch_reads_them(text, parsed):
    assert devices.parse_device(text) == parsed


@pytest.mark.parametrize(
    ("text", "words"),
    [("banana", "unknown device"), ("CUDA", "unknown device"), ("cuda:-1", "unknown device"),
     ("cuda:x", "unknown device"), ("", "unknown device"), ("mps", "is not supported"),
     ("xla:0", "is not supported")],
)  # fmt: skip
def test_devices_that_cannot_be_are_refused(text, words):
    with pytest.raises(InputError, match=words):
        devices.parse_device(text)


@pytest.mark.parametrize(
    ("visible", "ids"),
    [
        (None, ["0", "1"]),
        ("1,0", ["1", "0"]),
        ("1", ["1"]),
        ("", []),
        ("-1", []),
        ("0,5,1", ["0"]),  # the list ends at an index the driver does not have
        ("0,0,1", ["0"]),  # and at a repeat
        ("0,x,1", ["0"]),
        ("GPU-aa,GPU-bb,GPU-cc", ["GPU-aa", "GPU-bb"]),  # no more than the driver lists
    ],
)
def test_the_gpus_a_process_may_use_follow_cuda_visible_devices(monkeypatch, visible, ids):
    monkeypatch.setattr(devices, "_nvml_device_count", lambda: 2)
    if visible is None:
        monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    else:
        monkeypatch.setenv("CUDA_VISIBLE_DEVICES", visible)
    assert devices.visible_gpu_ids() == ids
    assert devices.cuda_device_count() == len(ids)


def test_a_gpu_index_past_the_last_is_refused(monkeypatch):
    monkeypatch.setattr(devices, "_nvml_device_count", lambda: 1)
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    devices.check_device("cuda")
    devices.check_device("cuda:0")
    with pytest.raises(InputError, match=r"device 'cuda:1': this machine has 1 CUDA device\(s\)"):
        devices.check_device("cuda:1")
    monkeypatch.setattr(devices, "_nvml_device_count", lambda: 0)
    devices.check_device("cpu")
    devices.check_device(None)  # the run decides: CUDA when usable
