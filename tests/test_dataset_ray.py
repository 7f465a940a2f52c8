"""`plantdreamer dataset` on its workers: the local pool (no address: worker processes of
this machine), a private local Ray (``--address local``, 2 CPUs), a two-node loopback
cluster, a SIGKILLed worker, a bad input among good ones, and a rerun that skips finished
plants.

The runs in this process (CliRunner) start and stop their own workers or local Ray, as a
user's do; the drivers run as subprocesses join one 2-CPU instance shared by the session
(conftest's ``shared_ray``: a Ray start-up costs 26-35 s on 2 cores), the two-node test
with two nodes added to it, or run on the pool. (Joined from this process after a local
instance had stopped, the shared one left the driver waiting.) Every process a test starts
is stopped: the command stops the workers and the local instance it starts, and the
fixtures their nodes.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.pipeline import GenerateConfig, generate_plants

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.slow

SMALL = {"guidance": "none", "steps": 20, "points": 2000, "eval_views": 1, "resolution": 32}
SMALL_FLAGS = ["--guidance", "none", "--steps", "20", "--points", "2000", "--eval-views", "1",
               "--resolution", "32", "--quiet", "--allow-empty-split"]  # fmt: skip


def on_shared(cluster):
    """The options that run a command on the shared instance instead of a local one."""
    return ["--address", cluster.address]


@pytest.fixture(params=["pool", "ray"])
def place(request):
    """Where a driver subprocess runs its plants, as options: the local pool (none), or the
    shared Ray instance."""
    if request.param == "pool":
        return []
    return on_shared(request.getfixturevalue("shared_ray"))


def loopback_env(**extra):
    """The environment of a driver subprocess, read when called (Ray may have added its
    auth token since import); on loopback only, as Ray would otherwise swap 127.0.0.1 for
    the machine's outward address."""
    return {**os.environ, "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", **extra}


def manifest(out_dir):
    return {
        r["id"]: r for r in map(json.loads, (out_dir / "manifest.jsonl").read_text().splitlines())
    }


def direct_ply(tmp_path, **settings):
    out = tmp_path / "direct" / f"{settings.get('species')}-{settings['seed']}"
    generate_plants([GenerateConfig.of(**{**SMALL, **settings})], out, show_progress=False)
    return (out / "plant.ply").read_bytes()


def listening_sockets():
    """(process name, address, port) of every TCP socket that this process (the Ray driver)
    and the processes it started (Ray's) listen on."""
    import psutil

    me = psutil.Process()
    names = {p.pid: p.name() for p in me.children(recursive=True)} | {me.pid: "driver"}
    return [
        (names[c.pid], c.laddr.ip, c.laddr.port)
        for c in psutil.net_connections("tcp")
        if c.status == psutil.CONN_LISTEN and c.pid in names
    ]


@pytest.fixture(scope="module")
def six_plants(tmp_path_factory):
    """Six plants on the local pool; with the sockets its driver and workers listened on,
    taken as the pool closes (its workers still up)."""
    from plantdreamer.dataset.local_pool import LocalPool

    out = tmp_path_factory.mktemp("six")
    args = ["dataset", "--species", "bean,mint,kale", "--count", "2", "--local-cpus", "2"]
    close, seen = LocalPool.close, {}

    def close_after_a_look(pool):
        seen["workers"] = [w.proc.pid for w in pool.workers if w.proc is not None]
        seen["sockets"] = listening_sockets()
        return close(pool)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(LocalPool, "close", close_after_a_look)
        result = CliRunner().invoke(main, [*args, *SMALL_FLAGS, "--out", str(out)])
    assert not ray.is_initialized()  # no Ray on one machine
    return out, args, result, seen


def test_the_local_pool_starts_no_ray_and_listens_on_nothing(six_plants):
    out, _, result, seen = six_plants
    assert result.exit_code == 0, result.output
    assert seen["sockets"] == []
    pids = {r["pid"] for r in manifest(out).values()}
    assert os.getpid() not in pids and len(pids) == 2  # two worker processes on 2 CPUs
    summary = json.loads((out / "dataset.json").read_text())
    assert summary["workers"] == {"on": "local pool", "address": None, "nodes": 1}
    import psutil

    assert not [p for p in seen["workers"] if psutil.pid_exists(p)]  # none left running


def test_a_local_ray_listens_on_loopback_only(tmp_path):
    """``--address local``: a private Ray on this machine, every socket on loopback."""
    from plantdreamer.dataset.engine import is_loopback

    shutdown, sockets = ray.shutdown, []

    def shutdown_after_a_look(*a, **kw):
        sockets.extend(listening_sockets())
        return shutdown(*a, **kw)

    args = ["dataset", "--species", "bean", "--address", "local", "--local-cpus", "2"]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ray, "shutdown", shutdown_after_a_look)
        result = CliRunner().invoke(main, [*args, *SMALL_FLAGS, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert not ray.is_initialized()  # the command stopped the Ray it started
    names = {name for name, _, _ in sockets}
    assert {"gcs_server", "raylet", "driver"} <= names, sockets
    assert any(name.startswith("ray::") for name in names)  # a worker, an agent
    assert [s for s in sockets if not is_loopback(s[1])] == []
    summary = json.loads((tmp_path / "dataset.json").read_text())
    assert summary["workers"]["on"] == "ray" and summary["workers"]["address"] == "local"


def test_six_plants_on_the_local_pool_match_direct_generate(six_plants, tmp_path):
    out, _, result, _ = six_plants
    assert result.exit_code == 0, result.output
    records = manifest(out)
    assert sorted(records) == sorted(
        f"{s}-s000{i}" for s in ("bean", "mint", "kale") for i in (0, 1)
    )
    for plant_id, record in records.items():
        assert record["status"] == "done" and record["error"] is None
        assert record["raster_threads"] == 1  # one CPU per plant with --guidance none
        assert "outputs" not in record  # the folder is the list of files
        assert (out / "plants" / plant_id / "run.json").is_file()
        species, seed = plant_id.split("-s")
        expected = direct_ply(tmp_path, species=species, seed=int(seed))
        assert (out / "plants" / plant_id / "plant.ply").read_bytes() == expected, plant_id
    summary = json.loads((out / "dataset.json").read_text())
    assert summary["state"] == "finished" and summary["totals"]["mint"] == {"done": 2}


def test_a_dataset_run_ends_with_splits_label_files_and_a_gallery(six_plants):
    out, _, result, _ = six_plants
    assert f"gallery: {out / 'gallery.png'}" in result.output
    splits = json.loads((out / "splits.json").read_text())
    assert sorted(splits["train"] + splits["val"] + splits["test"]) == sorted(manifest(out))
    # 0.8, 0.1, 0.1, each plant by its own hash: val drew none, said in a warning.
    assert [len(splits[s]) for s in ("train", "val", "test")] == [5, 0, 1]
    assert "warning: split val drew no plant" in result.output
    for split in ("train", "val", "test"):
        coco = json.loads((out / "coco" / f"{split}.json").read_text())
        assert len(coco["images"]) == len(splits[split])  # one view per plant
    assert (out / "yolo" / "data.yaml").is_file() and (out / "gallery.png").stat().st_size > 0


def test_rerun_skips_complete_plants(six_plants, monkeypatch):
    from plantdreamer.dataset import runner

    out, args, _, _ = six_plants
    monkeypatch.setattr(runner, "open_workers", lambda *a: pytest.fail("workers started"))
    before = (out / "manifest.jsonl").read_text()
    result = CliRunner().invoke(main, [*args, *SMALL_FLAGS, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "0 plants done, 6 skipped" in result.output
    assert (out / "manifest.jsonl").read_text() == before  # no timestamp moved


def test_scenes_of_the_finished_plants_join_a_rerun_without_training(six_plants, tmp_path):
    """`dataset --scenes` over complete plants: nothing trains (Ray is not started), the
    scenes are made from one split's plants each and join the split's label files."""
    out, args, _, _ = six_plants
    copy = shutil.copytree(out, tmp_path / "ds")
    scenes = ["--scenes", "0-3", "--scene-plants", "2", "--scene-layout", "random"]
    result = CliRunner().invoke(main, [*args, *SMALL_FLAGS, *scenes, "--out", str(copy)])
    assert result.exit_code == 0, result.output
    assert "0 plants done, 6 skipped" in result.output and "; scenes " in result.output
    splits = json.loads((copy / "splits.json").read_text())
    made = sorted(p.name for p in (copy / "scenes").iterdir())
    assert made == [f"scene-s{i:04d}" for i in range(4)]
    assert sorted(i for ids in splits["scenes"].values() for i in ids) == made
    for split, ids in splits["scenes"].items():
        coco = json.loads((copy / "coco" / f"{split}.json").read_text())
        shown = {
            i["file_name"].split("/")[1]
            for i in coco["images"]
            if i["file_name"].startswith("scenes/")
        }
        assert shown == set(ids)
        for scene in ids:
            record = json.loads((copy / "scenes" / scene / "scene.json").read_text())
            assert set(record["plant_ids"]) <= set(splits[split])


def test_bad_point_cloud_fails_alone(tmp_path):
    from plantdreamer.cloud import PointCloud
    from plantdreamer.io import write_ply

    clouds = tmp_path / "clouds"
    clouds.mkdir()
    rng = np.random.default_rng(0)
    for name in ("a", "b"):
        pts = (rng.normal(size=(3000, 3)) * [0.2, 0.2, 0.5]).astype(np.float32)
        write_ply(
            clouds / f"{name}.ply", PointCloud(pts, colors=rng.random((3000, 3), dtype=np.float32))
        )
    (clouds / "broken.ply").write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 5\nend_header\n1 2\n"
    )
    spec = tmp_path / "spec.toml"
    spec.write_text('[[group]]\npointclouds = "clouds/*.ply"\nspecies = "bean"\nsor_std = 100.0\n')
    out = tmp_path / "out"
    result = CliRunner().invoke(
        main, ["dataset", str(spec), "--local-cpus", "2", *SMALL_FLAGS, "--out", str(out)]
    )
    assert result.exit_code == 1
    assert "error: 1 of 3 plants failed" in result.output and "broken-s0000:" in result.output
    assert "Traceback" not in result.output
    records = manifest(out)
    assert {i: r["status"] for i, r in records.items()} == {
        "a-s0000": "done", "b-s0000": "done", "broken-s0000": "failed"
    }  # fmt: skip
    error = records["broken-s0000"]["error"]
    assert error and "\n" not in error and "ply" in error.lower()


def test_killed_worker_is_retried_and_resumes_byte_identical(tmp_path, place):
    out = tmp_path / "out"
    env = loopback_env(PLANTDREAMER_DATASET_HOLD="bean-s0001:12")
    cmd = [sys.executable, "-m", "plantdreamer.cli", "dataset", "--species", "bean", "--count", "2",
           *place, "--set", "checkpoint-every=5", *SMALL_FLAGS, "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        log = out / "plants" / "bean-s0001" / "generate.log"
        deadline = time.time() + 300
        while not (log.is_file() and "holding after step 12" in log.read_text()):
            assert proc.poll() is None and time.time() < deadline, "the plant never reached step 12"
            time.sleep(0.5)
        pid = manifest(out)["bean-s0001"]["pid"]
        os.kill(pid, signal.SIGKILL)
        output, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:  # stop it the way a user would, so it stops its Ray
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=120)
    assert proc.returncode == 0, output
    record = manifest(out)["bean-s0001"]
    assert record["status"] == "done" and record["attempt"] == 2 and record["pid"] != pid
    assert record["resumed_from_step"] == 10  # the checkpoint before the kill
    expected = direct_ply(tmp_path, species="bean", seed=1)
    assert (out / "plants" / "bean-s0001" / "plant.ply").read_bytes() == expected


@pytest.fixture
def two_nodes(shared_ray):
    """Two 1-CPU nodes with a ``plant_slot`` each, added to the shared instance (whose head
    has none: only these two can run a plant that asks for one); their node ids."""
    added = []
    try:
        for name in ("node_a", "node_b"):
            added.append(
                shared_ray.add_node(
                    num_cpus=1, resources={"plant_slot": 1, name: 1}, node_ip_address="127.0.0.1"
                )
            )
        shared_ray.wait_for_nodes()
        yield {n.node_id for n in added}
    finally:
        for node in added:
            shared_ray.remove_node(node)


def test_plants_spread_over_a_two_node_cluster(shared_ray, two_nodes, tmp_path):
    nodes = two_nodes
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "plantdreamer.cli", "dataset", "--species", "bean,kale",
           "--count", "2", *on_shared(shared_ray), "--resource", "plant_slot=1",
           *SMALL_FLAGS, "--out", str(out)]  # fmt: skip
    result = subprocess.run(cmd, env=loopback_env(), capture_output=True, text=True, timeout=400)
    assert result.returncode == 0, result.stderr[-3000:]
    records = manifest(out)
    assert all(r["status"] == "done" for r in records.values())
    assert {r["node"] for r in records.values()} == nodes  # both nodes ran plants


def _stopped_by(signum, out, place):
    """Runs two long plants at ``place``, sends ``signum`` to the driver once both have
    checkpointed, and returns its exit status, output and manifest."""
    cmd = [sys.executable, "-m", "plantdreamer.cli", "dataset", "--species", "bean", "--count",
           "2", *place, "--set", "checkpoint_every=5", *SMALL_FLAGS,
           "--steps", "100000", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(
        cmd, env=loopback_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        checkpoints = [out / "plants" / f"bean-s000{i}" / "checkpoint.pt" for i in (0, 1)]
        deadline = time.time() + 300
        while not all(c.is_file() for c in checkpoints):
            assert proc.poll() is None and time.time() < deadline, "the plants never started"
            time.sleep(0.5)
        proc.send_signal(signum)
        output, _ = proc.communicate(timeout=200)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=120)
    return proc.returncode, output, manifest(out)


def test_sigterm_stops_the_driver_as_ctrl_c_does(tmp_path, place):
    runs = {s: _stopped_by(s, tmp_path / s.name, place) for s in (signal.SIGINT, signal.SIGTERM)}
    shapes = {}
    for signum, (code, output, records) in runs.items():
        assert code == 130, output
        assert "interrupted" in output and "Traceback" not in output, output
        assert "error:" not in output and "Aborted" not in output, output
        for plant_id, record in records.items():
            folder = tmp_path / signum.name / "plants" / plant_id
            assert (folder / "checkpoint.pt").is_file(), plant_id
            assert record["error"].startswith("interrupted at step "), record
        shapes[signum] = {i: (r["status"], sorted(r)) for i, r in records.items()}
    assert shapes[signal.SIGINT] == shapes[signal.SIGTERM]
    assert {s for s, _ in shapes[signal.SIGTERM].values()} == {"interrupted"}


# -- --plants-per-gpu: packed groups ------------------------------------------------------

PACKED = ["dataset", "--species", "bean", "--count", "3", "--plants-per-gpu", "2",
          *SMALL_FLAGS]  # fmt: skip


def _files(folder):
    """Every file of a dataset folder by content, but those holding times and pids."""
    skip = {"run.json", "generate.log", "manifest.jsonl", "dataset.json"}
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name not in skip
    }


@pytest.fixture(scope="module")
def packed_twice(tmp_path_factory):
    runs = []
    for name in ("first", "second"):
        out = tmp_path_factory.mktemp(name)
        args = [*PACKED, "--local-cpus", "2", "--out", str(out)]
        runs.append((out, CliRunner().invoke(main, args)))
    return runs


def test_packed_plants_get_every_folder_record_and_export_and_the_same_bytes_twice(
    packed_twice, tmp_path
):
    (first, result), (second, again) = packed_twice
    assert result.exit_code == 0 and again.exit_code == 0, result.output + again.output
    records = manifest(first)
    assert {i: r["status"] for i, r in records.items()} == {
        f"bean-s000{i}": "done" for i in range(3)
    }
    assert records["bean-s0000"]["trained_with"] == ["bean-s0000", "bean-s0001"]
    assert records["bean-s0002"]["trained_with"] == ["bean-s0002"]  # a group of one
    assert {r["plants_per_gpu"] for r in records.values()} == {2}
    assert records["bean-s0000"]["raster_threads"] == 2  # the group's two CPUs
    assert json.loads((first / "dataset.json").read_text())["plants_per_gpu"] == 2
    assert not (first / "groups").exists()
    files = _files(first)
    assert files == _files(second)
    for split in ("coco/train.json", "yolo/data.yaml", "splits.json"):
        assert split in files
    for seed in range(3):  # without guidance, a plant of a group is the plant made alone
        ply = f"plants/bean-s000{seed}/plant.ply"
        assert files[ply] == direct_ply(tmp_path, species="bean", seed=seed), seed


def test_a_killed_group_worker_is_restarted_and_the_group_resumes_byte_identical(tmp_path, place):
    out = tmp_path / "out"
    env = loopback_env(PLANTDREAMER_DATASET_HOLD="bean-s0001:12")
    cmd = [sys.executable, "-m", "plantdreamer.cli", *PACKED, *place,
           "--set", "checkpoint-every=5", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        log = out / "plants" / "bean-s0001" / "generate.log"
        deadline = time.time() + 300
        while not (log.is_file() and "holding after step 12" in log.read_text()):
            assert proc.poll() is None and time.time() < deadline, "the group never reached step 12"
            time.sleep(0.5)
        pid = manifest(out)["bean-s0001"]["pid"]
        os.kill(pid, signal.SIGKILL)
        output, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=120)
    assert proc.returncode == 0, output
    records = manifest(out)
    for plant_id in ("bean-s0000", "bean-s0001"):  # the group ran again, from step 10
        record = records[plant_id]
        assert record["status"] == "done" and record["attempt"] == 2 and record["pid"] != pid
        assert record["resumed_from_step"] == 10
        seed = int(plant_id[-1])
        expected = direct_ply(tmp_path, species="bean", seed=seed)
        assert (out / "plants" / plant_id / "plant.ply").read_bytes() == expected


def test_the_dataset_example_makes_a_dataset_with_its_card_and_trains_a_detector(
    tmp_path, shared_ray
):
    """examples/dataset_and_detector.py as a user runs it (on the shared instance):
    ``make_dataset``, then a few Mask R-CNN iterations on its ``PlantViews``. The dataset
    has its card: README.md, dataset.json's ``card``, COCO's ``info`` and ``licenses``."""
    pytest.importorskip("torchvision")
    from pathlib import Path

    import plantdreamer

    out = tmp_path / "ds"
    example = Path(__file__).parents[1] / "examples" / "dataset_and_detector.py"
    done = subprocess.run(
        [sys.executable, str(example), str(out), shared_ray.address],
        env=loopback_env(), capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"2 plants in {out}; card: {out / 'README.md'}" in done.stdout
    assert [line.split(":")[0] for line in done.stdout.splitlines()[-2:]] == [
        f"iteration {i}" for i in (1, 2)
    ]
    card = json.loads((out / "dataset.json").read_text())["card"]
    assert card["plantdreamer"] == plantdreamer.__version__
    assert [(c["id"], c["name"]) for c in card["classes"]] == [
        (1, "leaf"), (2, "stem"), (3, "pot"), (4, "soil")
    ]  # fmt: skip
    assert card["species"] == {"bean": 2} and card["splits"]["train"]["plants"] == 2
    assert card["splits"]["train"]["images"] == 4  # two views per plant
    assert card["models"] == [] and card["licences"]["data"] == "unknown"  # no guidance
    assert card["licences"]["code"] == "Apache-2.0" and "2505.15528" in card["citation"]
    readme = (out / "README.md").read_text()
    assert readme.startswith("---\n") and "\n---\n# A plantdreamer dataset\n" in readme
    assert "| 1 | leaf | #1f77b4 | yes |" in readme and "| train | 2 | 4 | 2 bean |" in readme
    coco = json.loads((out / "coco" / "train.json").read_text())
    assert coco["info"]["version"] == plantdreamer.__version__
    assert coco["info"]["date_created"] == card["date"]
    assert [lic["id"] for lic in coco["licenses"]] == [1, 2]
    assert {image["license"] for image in coco["images"]} == {2}  # renders, no weights
