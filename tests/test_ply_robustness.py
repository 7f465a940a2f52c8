"""PLY files under hostile conditions: writes cut short by a file-size limit, headers that
lie about their sizes read under an address-space limit, files other tools write (extra
rows, broken faces) read as plyfile reads them, and header text other readers reject.

The limits run in subprocesses (resource.setrlimit), so the test process keeps its own."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import plyfile
import pytest

from plantdreamer.cloud import PointCloud
from plantdreamer.errors import InputError, PlyError, PlyWarning
from plantdreamer.io import read_ply, read_ply_columns, read_splat_ply, write_ply

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="uses Linux resource limits")


def _run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=300,
        env=os.environ,
    )


# --- 1. A write that fails part-way leaves the previous file intact --------------------

# Each writer writes ~1.2 MB; the limit is 64 KiB.
_WRITERS = {
    "write_ply binary": "write_ply(path, cloud, binary=True)",
    "write_ply ascii": "write_ply(path, cloud, binary=False)",
    "write_splat_ply": "write_splat_ply(path, gaussians)",
    "_core.write_ply_vertex": "_core.write_ply_vertex(path, [(['x', 'y', 'z'], big)])",
}

_WRITE_UNDER_LIMIT = """
    import resource, signal, sys
    import numpy as np
    from plantdreamer import _core
    from plantdreamer.cloud import PointCloud
    from plantdreamer.gaussians import Gaussians
    from plantdreamer.io import write_ply, write_splat_ply

    path = {path!r}
    rng = np.random.default_rng(0)
    big = rng.random((100_000, 3)).astype(np.float32)
    cloud = PointCloud(big, colors=rng.random((100_000, 3)).astype(np.float32))
    n = 5_000
    gaussians = Gaussians(
        means=big[:n], quats=rng.random((n, 4)).astype(np.float32),
        log_scales=big[:n] - 5, opacity_logits=big[:n, 0].copy(),
        sh=rng.random((n, 16, 3)).astype(np.float32),
    )
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a failed write, not a killed process
    resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536))
    try:
        {call}
    except OSError as e:
        print("OSError:", e)
        sys.exit(3)
    sys.exit(0)
"""


@pytest.mark.parametrize("writer", list(_WRITERS))
def test_a_write_cut_by_a_file_size_limit_keeps_the_old_file(tmp_path, writer):
    path = tmp_path / "good.ply"
    old = PointCloud(np.arange(12, dtype=np.float32).reshape(4, 3))
    write_ply(path, old)
    before = path.read_bytes()
    proc = _run(_WRITE_UNDER_LIMIT.format(path=str(path), call=_WRITERS[writer]))
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert "good.ply" in proc.stdout and "File too large" in proc.stdout, proc.stdout
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["good.ply"]  # no temporary file left behind
    np.testing.assert_array_equal(read_ply(path).positions, old.positions)


def test_a_write_replaces_the_file_and_leaves_nothing_else(tmp_path):
    path = tmp_path / "a.ply"
    for n in (5, 3):
        write_ply(path, PointCloud(np.zeros((n, 3), np.float32)))
        assert len(read_ply(path)) == n
    assert os.listdir(tmp_path) == ["a.ply"]


# --- 2. Headers that lie about their sizes: a clean PlyError under a memory limit ------


def _lying_header(fmt: str, count: int, props: int, lists: bool) -> bytes:
    head = ["ply", f"format {fmt} 1.0", f"element vertex {count}"]
    head += [f"property float p{i}" for i in range(props)]
    if lists:
        head.append("property list uchar int indices")
    head += ["element face 1", "property list uchar int vertex_indices", "end_header"]
    data = b"0 " * 100_000 if fmt == "ascii" else bytes(200_000)
    return ("\n".join(head) + "\n").encode() + data


# (format, claimed vertices, float properties, a list property too); each file is ~243 KB.
LYING = [
    (fmt, count, props, lists)
    for fmt in ("ascii", "binary_little_endian", "binary_big_endian")
    for count, props, lists in ((2**40, 2000, False), (2**40, 2000, True), (10**7, 1, True))
]

_READ_UNDER_LIMIT = """
    import resource, sys
    from plantdreamer import _core
    # Warm up first (thread pool, allocator arenas), then allow 1 GiB more address space.
    _core.read_ply_vertex(sys.argv[1])
    with open("/proc/self/status") as f:
        vm = next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize"))
    limit = vm + (1 << 30)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    for path in sys.argv[2:]:
        try:
            _core.read_ply_vertex(path)
            print("read", path)
        except _core.PlyError as e:
            print("PlyError", e)
"""


def test_lying_headers_are_rejected_under_an_address_space_limit(tmp_path):
    good = tmp_path / "good.ply"
    write_ply(good, PointCloud(np.zeros((10, 3), np.float32)))
    paths = []
    for i, case in enumerate(LYING):
        path = tmp_path / f"lying_{i}.ply"
        path.write_bytes(_lying_header(*case))
        assert 200_000 <= path.stat().st_size <= 260_000
        paths.append(str(path))
    proc = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(_READ_UNDER_LIMIT), str(good), *paths],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr  # an abort on allocation failure is 134
    lines = proc.stdout.splitlines()
    assert len(lines) == len(LYING), proc.stdout
    for line, (_, count, _, _) in zip(lines, LYING, strict=True):
        assert line.startswith("PlyError") and "lying header" in line, line
        assert str(count) in line


@pytest.mark.parametrize("case", LYING, ids=[f"{c[0]}-{c[1]}x{c[2]}" for c in LYING])
def test_lying_headers_name_the_claim(tmp_path, case):
    path = tmp_path / "lying.ply"
    path.write_bytes(_lying_header(*case))
    with pytest.raises(PlyError, match=f"declares {case[1]} rows") as info:
        read_ply(path)
    assert "lying.ply" in str(info.value) and "bytes" in str(info.value)


# --- 3. Other tools' files: read the declared rows and warn about the rest ------------

_VERTS = [(0.0, 1.0, 2.0), (3.0, 4.5, 5.0), (6.0, 7.0, -8.25)]
_HEAD = "ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\n" + (
    "property float z\n"
)


def _file(fmt: str, faces: str | None, tail: bytes) -> bytes:
    head = _HEAD.format(fmt=fmt)
    if faces is not None:
        head += f"element face {faces}\nproperty list uchar int vertex_indices\n"
    head += "end_header\n"
    if fmt == "ascii":
        body = "".join(" ".join(map(str, v)) + "\n" for v in _VERTS).encode()
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        body = np.array(_VERTS, dtype=f"{order}f4").tobytes()
    return head.encode() + body + tail


# name -> (format, face count, bytes after the vertices, what the warning says)
LENIENT = {
    "extra ascii row (MeshLab)": ("ascii", None, b"9 9 9\n", "more row"),
    "extra ascii row after faces": ("ascii", "1", b"3 0 1 2\n3 2 1 0\n", "more row"),
    "truncated ascii faces": ("ascii", "2", b"3 0 1 2\n", "truncated"),
    "short ascii face list": ("ascii", "1", b"3 0 1\n", "shorter than its length"),
    "non-numeric ascii face": ("ascii", "1", b"3 0 one 2\n", "not a number"),
    "non-text ascii face": ("ascii", "1", b"3 0 1 \xff\n", "not text"),
    "truncated binary faces (le)": ("binary_little_endian", "2", b"\x03" + bytes(12), "truncated"),
    "truncated binary faces (be)": ("binary_big_endian", "1", b"\x03" + bytes(5), "truncated"),
    "binary face count past the file": ("binary_little_endian", "1099511627776", b"", "face"),
    "binary bytes after the last element": ("binary_little_endian", None, bytes(7) + b"x", "after"),
}


@pytest.mark.parametrize("name", list(LENIENT))
def test_a_whole_vertex_element_is_read_with_a_warning(tmp_path, name):
    fmt, faces, tail, needle = LENIENT[name]
    path = tmp_path / "other_tool.ply"
    path.write_bytes(_file(fmt, faces, tail))
    with pytest.warns(PlyWarning, match=needle) as record:
        cloud = read_ply(path)
    assert len(record) == 1 and "other_tool.ply" in str(record[0].message)
    assert record[0].filename == __file__  # the warning points at the caller
    np.testing.assert_array_equal(cloud.positions, np.array(_VERTS, np.float32))
    with pytest.warns(PlyWarning):
        assert list(read_ply_columns(path)) == ["x", "y", "z"]
    with pytest.raises(PlyError, match=needle):
        read_ply(path, strict=True)
    with pytest.raises(PlyError, match=needle):
        read_ply_columns(path, strict=True)


@pytest.mark.parametrize("name", list(LENIENT))
def test_lenient_reads_agree_with_plyfile(tmp_path, name):
    """Where plyfile reads such a file, it returns the same vertices; where it refuses the
    file, the strict read refuses it too."""
    fmt, faces, tail, _ = LENIENT[name]
    path = tmp_path / "other_tool.ply"
    path.write_bytes(_file(fmt, faces, tail))
    try:
        theirs = plyfile.PlyData.read(str(path))["vertex"]
    except Exception:
        with pytest.raises(PlyError):
            read_ply(path, strict=True)
        return
    with pytest.warns(PlyWarning):
        ours = read_ply(path).positions
    for axis, coord in enumerate("xyz"):
        np.testing.assert_array_equal(ours[:, axis], theirs[coord])


def test_meshlab_extra_row_is_read_as_plyfile_reads_it(tmp_path):
    # The MeshLab case checked against plyfile explicitly (it must read it).
    path = tmp_path / "meshlab.ply"
    path.write_bytes(_file("ascii", None, b"9 9 9\n"))
    theirs = plyfile.PlyData.read(str(path))["vertex"]
    with pytest.warns(PlyWarning, match="1 more row"):
        ours = read_ply(path)
    assert len(ours) == len(theirs) == 3


def test_splat_reader_warns_and_strict_raises(tmp_path):
    from plantdreamer.gaussians import Gaussians
    from plantdreamer.io import write_splat_ply

    n = 4
    g = Gaussians(
        means=np.zeros((n, 3), np.float32),
        quats=np.ones((n, 4), np.float32),
        log_scales=np.zeros((n, 3), np.float32),
        opacity_logits=np.zeros(n, np.float32),
        sh=np.zeros((n, 1, 3), np.float32),
    )
    path = tmp_path / "g.ply"
    write_splat_ply(path, g)
    path.write_bytes(path.read_bytes() + b"garbage")
    with pytest.warns(PlyWarning, match="after the last element"):
        assert len(read_splat_ply(path)) == n
    with pytest.raises(PlyError):
        read_splat_ply(path, strict=True)


@pytest.mark.parametrize(
    "content",
    [
        _file("ascii", None, b"")[:-7],  # the vertex element itself is cut
        _file("binary_little_endian", None, b"")[:-1],
        _file("ascii", None, b"").replace(b"4.5", b"four"),
    ],
)
def test_problems_in_the_vertex_element_stay_errors(tmp_path, content):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning either
        with pytest.raises(PlyError):
            read_ply(path)


# --- 4. Header text: written so that plyfile reads it back, or refused ---------------


@pytest.mark.parametrize(
    ("attributes", "comments", "needle"),
    [
        ({"\u00e9t\u00e9": np.zeros(2, np.float32)}, (), "property name"),
        ({"\u6e29\u5ea6": np.zeros(2, np.int32)}, (), "property name"),
        ({}, ("caf\u00e9",), "comment"),
        ({}, ("\u6e29\u5ea6 = 3",), "comment"),
    ],
)
def test_non_ascii_header_text_is_refused_on_write(tmp_path, attributes, comments, needle):
    path = tmp_path / "a.ply"
    cloud = PointCloud(np.zeros((2, 3), np.float32), attributes=attributes)
    with pytest.raises(InputError, match=f"{needle}.*must be ASCII"):
        write_ply(path, cloud, comments=comments)
    assert not path.exists()


def test_ascii_header_text_round_trips_through_plyfile(tmp_path):
    path = tmp_path / "a.ply"
    cloud = PointCloud(np.zeros((2, 3), np.float32), attributes={"a_b-c.d": np.ones(2, np.int32)})
    write_ply(path, cloud, comments=["made by: a test (ok)", "tabs\tand ~symbols~"])
    data = plyfile.PlyData.read(str(path))
    assert data.comments == ["made by: a test (ok)", "tabs\tand ~symbols~"]
    np.testing.assert_array_equal(data["vertex"]["a_b-c.d"], [1, 1])
