"""``plantdreamer lsystem``: listing, mesh and point-cloud files, determinism, errors."""

import subprocess
import sys

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from plantdreamer.cli import main


def run(*args):
    return CliRunner().invoke(main, ["lsystem", *args])


def test_list_names_every_species():
    result = run("--list")
    assert result.exit_code == 0
    names = [line.split()[0] for line in result.output.splitlines()]
    assert names == ["bean", "bean-released", "kale", "kale-released", "mint", "mint-released"]


def test_mesh_is_written_and_reads_back(tmp_path):
    path = tmp_path / "plant.glb"
    result = run("mint", "--seed", "3", "--mesh", str(path))
    assert result.exit_code == 0, result.output
    assert "mint seed 3" in result.output
    loaded = trimesh.load(path, force="mesh")
    from plantdreamer.lsystem import generate_plant

    mesh = generate_plant("mint", 3)
    assert len(loaded.faces) == len(mesh.faces)
    np.testing.assert_allclose(
        np.sort(loaded.vertices[:, 2]), np.sort(mesh.vertices[:, 2]), atol=1e-6
    )


def test_mesh_files_are_byte_identical_across_processes(tmp_path):
    paths = [tmp_path / "a.glb", tmp_path / "b.glb", tmp_path / "c.glb"]
    for path, seed in zip(paths, ["5", "5", "6"], strict=True):
        subprocess.run(
            [
                sys.executable,
                "-m",
                "plantdreamer",
                "lsystem",
                "kale",
                "--seed",
                seed,
                "--mesh",
                path,
            ],
            check=True,
            capture_output=True,
        )
    a, b, c = (p.read_bytes() for p in paths)
    assert a == b
    assert a != c


def test_point_cloud_ply_is_deterministic_and_labelled(tmp_path):
    pytest.importorskip("plantdreamer.io")
    plyfile = pytest.importorskip("plyfile")
    paths = [tmp_path / "a.ply", tmp_path / "b.ply"]
    for path in paths:
        result = run("bean", "--seed", "2", "-o", str(path), "--points", "5000")
        assert result.exit_code == 0, result.output
    assert paths[0].read_bytes() == paths[1].read_bytes()
    vertex = plyfile.PlyData.read(str(paths[0]))["vertex"]
    assert len(vertex) == 5000
    names = vertex.data.dtype.names
    for name in ("x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "label", "instance"):
        assert name in names
    assert set(np.unique(vertex["label"])) <= {1, 2, 3, 4}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["oak", "--mesh", "{d}/x.glb"], "unknown species 'oak'"),
        (["bean"], "nothing to write"),
        ([], "name a SPECIES"),
        (["bean", "--mesh", "{d}/x.xyz"], "unknown mesh format"),
        (["bean", "--seed", "-1", "--mesh", "{d}/x.glb"], "-1"),
        (["bean", "--points", "0", "-o", "{d}/x.ply"], "0"),
        (["bean", "--mesh", "{d}/missing/x.glb"], "error: "),
    ],
)
def test_bad_requests_fail_with_one_clear_line(tmp_path, args, message):
    result = run(*(a.format(d=tmp_path) for a in args))
    assert result.exit_code != 0
    assert message in result.output
    assert "Traceback" not in result.output
    assert not list(tmp_path.iterdir())  # nothing half-written


def test_point_cloud_without_the_ply_module_is_one_clear_line(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "plantdreamer.io", None)  # as if it were not installed
    result = run("bean", "-o", str(tmp_path / "x.ply"))
    assert result.exit_code == 1
    assert "error: -o needs plantdreamer.io" in result.output
    assert not list(tmp_path.iterdir())


def test_mesh_files_carry_organ_labels_and_leaf_instances(tmp_path):
    plyfile = pytest.importorskip("plyfile")
    from plantdreamer.lsystem import generate_plant

    mesh = generate_plant("bean", 1)
    ply, glb = tmp_path / "bean.ply", tmp_path / "bean.glb"
    assert run("bean", "--seed", "1", "--mesh", str(ply)).exit_code == 0
    assert run("bean", "--seed", "1", "--mesh", str(glb)).exit_code == 0
    vertex = plyfile.PlyData.read(str(ply))["vertex"]
    np.testing.assert_array_equal(vertex["label"], mesh.labels)
    np.testing.assert_array_equal(vertex["instance"], mesh.instances)
    loaded = trimesh.load(glb, force="mesh", process=False)
    np.testing.assert_array_equal(loaded.vertex_attributes["_label"].ravel(), mesh.labels)
    np.testing.assert_array_equal(loaded.vertex_attributes["_instance"].ravel(), mesh.instances)


def test_point_cloud_option_hands_the_sampled_cloud_to_write_ply(tmp_path, monkeypatch):
    # Checks the wiring without the PLY module: a stand-in records what it is given.
    import types

    from plantdreamer.cloud import PointCloud

    calls = []
    fake = types.ModuleType("plantdreamer.io")
    fake.write_ply = lambda path, cloud, binary: calls.append((path, cloud, binary))
    monkeypatch.setitem(sys.modules, "plantdreamer.io", fake)
    result = run("kale", "--seed", "4", "-o", str(tmp_path / "k.ply"), "--points", "1234")
    assert result.exit_code == 0, result.output
    (path, cloud, binary), *rest = calls
    assert not rest and binary is True and str(path) == str(tmp_path / "k.ply")
    assert isinstance(cloud, PointCloud) and len(cloud) == 1234
    assert set(cloud.attributes) == {"label", "instance"}
    assert cloud.colors is not None and cloud.normals is not None


def test_a_growth_stage_is_the_younger_plant_and_a_bad_one_is_refused(tmp_path):
    from plantdreamer.lsystem import generate_plant

    result = run("bean", "--seed", "2", "--growth", "0.5", "--mesh", str(tmp_path / "b.ply"))
    assert result.exit_code == 0, result.output
    young = generate_plant("bean", 2, growth=0.5)
    assert f"{young.n_leaves} leaves" in result.output
    assert young.n_leaves < generate_plant("bean", 2).n_leaves
    assert len(trimesh.load(tmp_path / "b.ply", process=False).faces) == len(young.faces)
    for bad in ("0", "1.5"):  # click's range: a usage error
        refused = run("bean", "--growth", bad, "--mesh", str(tmp_path / "c.ply"))
        assert refused.exit_code == 2 and "--growth" in refused.output
    refused = run("bean", "--growth", "nan", "--mesh", str(tmp_path / "c.ply"))
    assert refused.exit_code == 1 and "error: growth must be a stage in (0, 1]" in refused.output
    assert not (tmp_path / "c.ply").exists()
