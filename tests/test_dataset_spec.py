"""Dataset specs, config hashes, the folder lock and the missing-Ray message (no Ray started)."""

import builtins

import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.dataset import config_hash, expand, load_spec
from plantdreamer.dataset.demand import plant_demand
from plantdreamer.dataset.engine import RAY_MISSING, is_loopback
from plantdreamer.dataset.lock import dataset_lock
from plantdreamer.dataset.ray_token import private_token
from plantdreamer.dataset.ray_workers import actor_options
from plantdreamer.errors import InputError
from plantdreamer.pipeline import GenerateConfig


def test_groups_expand_to_plants_with_settings_passed_through(tmp_path):
    (tmp_path / "scans").mkdir()
    for name in ("b.ply", "a.ply"):
        (tmp_path / "scans" / name).write_bytes(b"")
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(
        "[defaults]\nsteps = 20\neval-views = 2\n\n"
        '[[group]]\nspecies = "bean"\ncount = 2\nseed-start = 5\npoints = 3000\n\n'
        '[[group]]\nname = "scan"\npointclouds = "scans/*.ply"\nspecies = "mint"\n'
        'seeds = [1]\nguidance = "none"\n'
    )
    plants = expand(load_spec(spec_file))
    assert [p.id for p in plants] == ["bean-s0005", "bean-s0006", "scan-a-s0001", "scan-b-s0001"]
    bean, scan = plants[0].config, plants[2].config
    assert (bean.get("steps"), bean.get("eval-views"), bean.get("points"), bean.seed) == (
        20,
        2,
        3000,
        5,
    )
    assert bean.get("guidance") == "sds" and scan.get("guidance") == "none"
    assert scan.source.pointcloud == str((tmp_path / "scans" / "a.ply").resolve())
    assert plants[2].source == scan.source.pointcloud and plants[0].source == "lsystem"


def test_a_preset_in_the_spec_applies_under_the_spec_settings(tmp_path):
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(
        '[defaults]\npreset = "released"\n\n'
        '[[group]]\nspecies = "bean"\nseeds = [0]\npoints = 5000\n'
    )
    (plant,) = expand(load_spec(spec_file))
    cfg = plant.config
    assert cfg.preset == "released"
    # The preset's values, except where the spec sets its own.
    assert (cfg.density.cull.threshold, cfg.sds.depth_rule, cfg.sds.guidance_scale) == (
        7.0,
        "released",
        101.0,
    )
    assert cfg.source.points == 5000
    assert plant.config_hash != config_hash(GenerateConfig.of(species="bean", seed=0, points=5000))


@pytest.mark.parametrize(
    ("group", "message"),
    [
        ('species = "bean"\nsteps_typo = 3', "unknown setting 'steps-typo'; did you mean 'steps'"),
        ('species = "bean"\nseeds = [1, 1]', "distinct seeds"),
        ('species = "bean"\nseeds = [1]\ncount = 2', "give 'seeds' once"),
        ('species = "bean"\nseed = 3', "chosen per group"),
        ('pointcloud = "nothing/*.ply"', "no files match"),
        ("count = 2", "needs 'species' or 'pointcloud'"),
        ('species = "bean"\ncolor_init = "blue"', "color init must be one of"),
        ('species = "bean"\ngrowth = [0.5, 1.5]', r"growth must be in \(0, 1\], got 1.5"),
        ('species = "bean"\ngrowth = "0-1/3"', r"growth must be in \(0, 1\], got 0.0"),
        ('species = "bean"\ngrowth = "0.5-0.25/2"', "is no range of stages"),
        ('species = "bean"\ngrowth = "half"', "'half' is no stage or range"),
        ('species = "bean"\ngrowth = [0.5, 1]\ngrowth_since = 0.25', "sets growth-since itself"),
    ],
)
def test_bad_groups_are_clear_errors(tmp_path, group, message):
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(f"[[group]]\n{group}\n")
    with pytest.raises(InputError, match=message):
        expand(load_spec(spec_file))


def test_a_growth_series_is_each_seeds_plant_at_every_stage():
    spec = {
        "defaults": {"points": 500},
        "group": [
            {"species": "bean", "seeds": "0-1", "growth": "0.25-1/4"},
            {"name": "young", "species": "mint", "growth": 0.5},
            {"name": "listed", "species": "kale", "growth": [1, 0.3, 0.3]},
        ],
    }
    plants = expand(spec)
    series = [(p.id, p.config.source.growth, p.config.source.growth_since) for p in plants]
    assert series[:4] == [
        ("bean-s0000-g0.25", 0.25, None),
        ("bean-s0000-g0.5", 0.5, 0.25),
        ("bean-s0000-g0.75", 0.75, 0.5),
        ("bean-s0000-g1", 1.0, 0.75),
    ]
    assert [s[0] for s in series[4:8]] == [f"bean-s0001-g{g}" for g in ("0.25", "0.5", "0.75", "1")]
    # One stage is a setting like any other: no series, no suffix.
    assert series[8] == ("young-mint-s0000", 0.5, None)
    assert series[9:] == [("listed-kale-s0000-g0.3", 0.3, None), ("listed-kale-s0000-g1", 1.0, 0.3)]
    # Each stage's config (and so its hash) is its own: the seed's plants never clash.
    assert len({p.config_hash for p in plants}) == len(plants)


def test_same_ids_in_two_groups_are_refused():
    spec = {"group": [{"species": "bean"}, {"species": "bean"}]}
    with pytest.raises(InputError, match="appears twice"):
        expand(spec)


def test_config_hash_is_stable_and_sees_every_setting():
    a = GenerateConfig.of(species="bean", seed=1)
    assert config_hash(a) == config_hash(GenerateConfig.from_dict(a.to_dict()))
    assert config_hash(a) != config_hash(GenerateConfig.of(species="bean", seed=2))
    b = GenerateConfig.of(species="bean", seed=1)
    b.train.lr.means *= 2
    assert config_hash(a) != config_hash(b)


def test_settings_that_only_watch_a_run_leave_a_plants_hash_as_it_was():
    """Progress pictures and TensorBoard change no output of a plant: a dataset made before
    these settings existed (the hash below: 4de445f's of this config) keeps its plants."""
    a = GenerateConfig.of(species="bean", seed=1)
    watched = GenerateConfig.of(species="bean", seed=1, progress_every=5, tensorboard=True)
    assert config_hash(a) == config_hash(watched) == "8978d80172728769"


def test_resources_follow_guidance_and_overrides():
    sds = plant_demand(GenerateConfig.of(species="bean"), None, None, {})
    none = plant_demand(GenerateConfig.of(species="bean", guidance="none"), None, None, {})
    assert (sds.gpus, none.gpus) == (1.0, 0.0) and none.threads == 1
    custom = plant_demand(GenerateConfig.of(species="bean"), 3.5, 0.5, {"slot": 1})
    assert (custom.cpus, custom.gpus, custom.threads) == (3.5, 0.5, 3)
    options = actor_options(custom, max_retries=2, extra_env={})
    assert options["resources"] == {"slot": 1} and options["max_task_retries"] == 2
    assert options["runtime_env"]["env_vars"]["RAYON_NUM_THREADS"] == "3"
    # A packed group: one plant's GPU, every plant's CPUs (its renders run in parallel).
    group = plant_demand(GenerateConfig.of(species="bean"), None, None, {}, plants_per_gpu=4)
    assert (group.cpus, group.gpus, group.threads) == (8.0, 1.0, 8)


def test_a_second_process_on_the_same_folder_is_refused(tmp_path):
    with dataset_lock(tmp_path):
        result = CliRunner().invoke(
            main, ["dataset", "--species", "bean", "--guidance", "none", "--out", str(tmp_path)]
        )
    assert result.exit_code == 1
    assert "another `plantdreamer dataset`" in result.output and "Traceback" not in result.output
    with dataset_lock(tmp_path):  # released when the holder is done
        pass


def test_without_ray_the_command_says_what_to_install(tmp_path, monkeypatch):
    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray" or name.startswith("ray."):
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    args = ["dataset", "--species", "bean", "--address", "auto", "--out", str(tmp_path)]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 1
    assert RAY_MISSING in result.output
    assert "pip install 'plantdreamer[cluster]'" in result.output
    assert not (tmp_path / "plants").exists()


def test_dataset_seeds_name_the_plants_generate_seeds_names(tmp_path):
    """`dataset --seeds 0-3 --species bean` and `generate --seeds 0-3 --species bean`: the
    same plants (ids as generate's folders, the same settings), whatever spelling of the set."""
    import json

    from plantdreamer.cli import generate as generate_cli

    generate = CliRunner().invoke(main, ["generate", "--species", "bean", "--seeds", "0-3",
                                         "--guidance", "none", "--print-config"])  # fmt: skip
    assert generate.exit_code == 0, generate.output
    shown = [c["config"] for c in json.loads(generate.output)]
    named = [f"{c['species']}-s{c['seed']:04d}" for c in shown]
    assert named == ["bean-s0000", "bean-s0001", "bean-s0002", "bean-s0003"]
    for seeds in (["--seeds", "0-3"], ["--seeds", "0,1,2-3"], ["--count", "4"],
                  ["--seeds", "0-3", "--count", "4", "--seed-start", "0"]):  # fmt: skip
        result = CliRunner().invoke(main, ["dataset", "--species", "bean", *seeds, "--guidance",
                                           "none", "--dry-run", "--allow-empty-split", "--out",
                                           str(tmp_path)])  # fmt: skip
        assert result.exit_code == 0, result.output
        assert [line.split()[-1] for line in result.output.splitlines()[1:]] == named, seeds
    args = ["--species", "bean", "--guidance", "none"]
    with generate_cli.generate.make_context("generate", args) as ctx:
        made = generate_cli._configs(dict(ctx.params), "0-3")
    spec = {"group": [{"species": "bean", "seeds": "0-3"}], "defaults": {"guidance": "none"}}
    assert [p.config for p in expand(spec)] == made


@pytest.mark.parametrize(
    ("group", "message"),
    [
        ({"seeds": "0-3", "count": 3}, "name seeds 0-2 and 'seeds' 0-3; give 'seeds' once"),
        ({"seeds": "3-1"}, "3-1 is a reversed range"),
        ({"seeds": "0,0"}, "distinct seeds"),
        ({"seeds": 3}, "'seeds' must be ranges"),
        ({"pointcloud": "a.ply", "pointclouds": "b.ply"}, "give 'pointcloud' once"),
    ],
)
def test_a_groups_earlier_spelling_beside_its_new_one_must_agree(tmp_path, group, message):
    (tmp_path / "a.ply").write_bytes(b"")
    spec = {"base_dir": str(tmp_path), "group": [{"species": "bean", **group}]}
    with pytest.raises(InputError, match=message):
        expand(spec)


def test_a_group_spells_seeds_and_pointcloud_as_the_options_do(tmp_path):
    (tmp_path / "a.ply").write_bytes(b"")
    new = {"base_dir": str(tmp_path), "group": [
        {"species": "bean", "pointcloud": "a.ply", "seeds": "2-3,7"}]}  # fmt: skip
    old = {"base_dir": str(tmp_path), "group": [
        {"species": "bean", "pointclouds": "a.ply", "seeds": [2, 3, 7]}]}  # fmt: skip
    same = {"base_dir": str(tmp_path), "group": [
        {"species": "bean", "pointcloud": "a.ply", "pointclouds": "a.ply", "seeds": "2-3",
         "count": 2, "seed-start": 2}]}  # fmt: skip
    assert [p.id for p in expand(new)] == ["a-s0002", "a-s0003", "a-s0007"]
    assert [p.config for p in expand(old)] == [p.config for p in expand(new)]
    assert [p.id for p in expand(same)] == ["a-s0002", "a-s0003"]
    folder = str(tmp_path / "a.ply")
    result = CliRunner().invoke(main, ["dataset", "--pointcloud", folder, "--species", "bean",
                                       "--seeds", "2-3,7", "--dry-run", "--allow-empty-split", "--out",
                                       str(tmp_path / "d")])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert [line.split()[-1] for line in result.output.splitlines()[1:]] == [
        "a-s0002", "a-s0003", "a-s0007"]  # fmt: skip


def test_log_mode_numbers_each_finished_plant_and_gives_the_time_left(capsys, monkeypatch):
    """Without a terminal (Slurm, nohup) each finished plant is one line: [k/N], its status,
    its time, and the time left at the rate so far."""
    from plantdreamer.dataset import display

    clock = iter([100.0, 130.0, 160.0])  # start, then two plants 30 s apart
    monkeypatch.setattr(display.time, "monotonic", lambda: next(clock))
    progress = display.DatasetProgress(4, enabled=True)
    progress.finished("bean-s0000", {"status": "done", "seconds": 28.0})
    progress.finished("bean-s0001", {"status": "failed", "error": "no such file"})
    lines = capsys.readouterr().err.splitlines()
    assert lines == [
        "[1/4] done        bean-s0000  28.0 s  eta 1 min 30 s",
        "[2/4] failed      bean-s0001  no such file  eta 1 min 00 s",
    ]


def test_a_local_ray_without_token_authentication_is_refused(tmp_path, monkeypatch):
    pytest.importorskip("ray")
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    args = ["dataset", "--species", "bean", "--guidance", "none", "--allow-empty-split",
            "--address", "local"]  # fmt: skip
    result = CliRunner().invoke(main, [*args, "--out", str(tmp_path)])
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert "error: RAY_AUTH_MODE=disabled would start the local Ray without token" in result.output
    assert "--address" in result.output  # how to choose otherwise


def test_the_ray_token_file_is_readable_by_its_owner_alone(tmp_path):
    token = tmp_path / ".ray" / "auth_token"
    private_token(token)
    assert oct(token.stat().st_mode & 0o777) == "0o600" and len(token.read_text()) == 64
    before = token.read_bytes()
    private_token(token)  # kept as it is
    assert token.read_bytes() == before and list(token.parent.iterdir()) == [token]
    token.chmod(0o644)
    with pytest.warns(UserWarning, match="readable by other users"):
        private_token(token)
    assert oct(token.stat().st_mode & 0o777) == "0o600" and token.read_bytes() == before


@pytest.mark.parametrize(
    ("host", "loopback"),
    [("127.0.0.1", True), ("127.3.2.1", True), ("::1", True), ("::ffff:127.0.0.1", True),
     ("0.0.0.0", False), ("::", False), ("192.0.2.2", False), ("::ffff:192.0.2.2", False)],
)  # fmt: skip
def test_loopback_addresses(host, loopback):
    assert is_loopback(host) is loopback
