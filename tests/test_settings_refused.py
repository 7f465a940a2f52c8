"""Impossible settings are refused before anything runs, with one ``error:`` line, in
``generate``, ``generate --print-config`` and ``dataset --set``; ``--seeds`` never drops a
range silently; ``--print-config`` of a huge step count returns at once."""

import json
import time

import pytest

from cli_run import one_error, run

GEN = ["generate", "--species", "bean", "--guidance", "none", "--steps", "0", "--points", "300",
       "--resolution", "16", "--eval-views", "1", "--turntable", "none", "--quiet"]  # fmt: skip


# (options, the --set form for dataset, a part of the message)
IMPOSSIBLE = [
    (["--eval-fovy-deg", "0"], "eval-fovy-deg=0", "eval-fovy-deg"),
    (["--eval-fovy-deg", "180"], "eval-fovy-deg=180", "eval-fovy-deg"),
    (["--eval-distance", "0"], "eval-distance=0", "eval-distance"),
    (["--cameras-distance", "6", "3"], "cameras-distance=[6, 3]", "cameras-distance"),
    (["--elevation-sampling", "mixed", "--cameras-elevation-deg", "100", "120"],
     "cameras-elevation-deg=[100, 120]", "cameras-elevation-deg"),
    (["--cameras-fovy-deg", "170", "200"], "cameras-fovy-deg=[170, 200]", "cameras-fovy-deg"),
    (["--cull-threshold", "-100"], "cull-threshold=-100", "cull-threshold"),
    (["--lr-means", "-1"], "lr-means=-1", "lr-means"),
    (["--turntable-frames", "-1"], "turntable-frames=-1", "turntable-frames"),
    (["--scene-size", "0"], "scene-size=0", "scene-size must be in [0.1, 1e+06]"),
    (["--scene-size", "1e9"], "scene-size=1e9", "scene-size must be in [0.1, 1e+06]"),
    (["--opacity-init", "0"], "opacity-init=0", "opacity-init must be in (0, 1)"),
    (["--opacity-init", "1"], "opacity-init=1", "opacity-init must be in (0, 1)"),
    (["--lr-means", "1e39"], "lr-means=1e39", "lr-means must be in [0, 1e+06]"),
    (["--rig-distance", "1", "2"], "rig-distance=[1, 2]", "apply to the drawn rigs, not --rig orbit"),
    (["--jitter-brightness", "2"], "jitter-brightness=2", "jitter-brightness must be in [0, 1]"),
    (["--background-colour", "2", "0", "0"], "background-colour=[2, 0, 0]",
     "background-colour must be R G B in [0, 1]"),
    (["--rig", "transforms"], "rig=transforms", "--rig transforms and --rig-transforms FILE"),
]  # fmt: skip


@pytest.mark.parametrize(("options", "_", "message"), IMPOSSIBLE)
def test_generate_refuses_impossible_settings_before_anything_runs(tmp_path, options, _, message):
    out = tmp_path / "o"
    one_error(run(*GEN, "--out", out, *options), message)
    assert not out.exists() or not any(out.iterdir())
    one_error(run(*GEN, "--print-config", *options), message)


@pytest.mark.parametrize(("_", "setting", "message"), IMPOSSIBLE)
def test_dataset_set_refuses_impossible_settings_before_ray(tmp_path, _, setting, message):
    if setting.startswith("cameras-elevation"):
        setting_args = ["--set", "elevation-sampling=mixed", "--set", setting]
    else:
        setting_args = ["--set", setting]
    out = tmp_path / "d"
    result = run("dataset", "--species", "bean", "--guidance", "none", "--steps", "0",
                 *setting_args, "--out", out)  # fmt: skip
    one_error(result, message)
    assert not out.exists()


@pytest.mark.parametrize("seeds", ["5-2,7", "5-2", "7,5-2"])
def test_a_reversed_seed_range_is_refused_not_dropped(tmp_path, seeds):
    from plantdreamer.errors import InputError
    from plantdreamer.pipeline.settings.group_settings import parse_group_seeds as parse_seeds

    with pytest.raises(InputError, match="5-2 is a reversed range; write 2-5"):
        parse_seeds(seeds)
    one_error(run(*GEN, "--seeds", seeds, "--out", tmp_path / "g"), "reversed range")
    assert not (tmp_path / "g").exists()


def test_print_config_of_a_billion_steps_returns_at_once():
    started = time.perf_counter()
    result = run(*GEN, "--steps", "1000000000", "--cull-every", "1", "--print-config")
    seconds = time.perf_counter() - started
    assert result.exit_code == 0, result.output
    (shown,) = json.loads(result.output)  # one plant: a list of one
    assert shown["cull_steps"] == {"first": 501, "last": 999_999_999, "every": 1,
                                   "count": 999_999_499}  # fmt: skip
    assert shown["densify_steps"] == {"first": 400, "last": 800, "every": 100, "count": 5}
    assert seconds < 30, seconds  # enumerating a billion steps takes minutes and gigabytes


@pytest.mark.parametrize(
    ("steps", "start", "until", "every", "offset", "after"),
    [(3600, 300, 900, 100, 1, 500), (10, 300, 900, 100, 0, 500), (1000, 0, 1000, 7, 3, 0),
     (50, 10, 40, 1, 0, 49), (801, 300, 5000, 100, 0, 700)],
)  # fmt: skip
def test_schedule_steps_match_the_rules_step_by_step(steps, start, until, every, offset, after):
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.settings.resolved import resolved_settings, steps_of

    cfg = GenerateConfig.of(
        species="bean", guidance="none", steps=steps, densify_start=start, densify_until=until,
        densify_every=every, cull_every=every, cull_offset=offset, cull_after=after,
    )  # fmt: skip
    (shown,) = resolved_settings([cfg])
    for key, due in (
        ("densify_steps", cfg.density.densify.due),
        ("cull_steps", cfg.density.cull.due),
    ):
        assert steps_of(shown[key]) == [s for s in range(steps) if due(s)], key


def test_eval_views_are_bounded_in_every_form(tmp_path):
    from plantdreamer.pipeline.outputs import MAX_EVAL_VIEWS

    result = run(*GEN, "--eval-views", 10**9, "--print-config")
    assert result.exit_code == 2 and f"0<=x<={MAX_EVAL_VIEWS}" in result.output
    result = run("dataset", "--species", "bean", "--guidance", "none", "--steps", "0",
                 "--set", "eval-views=1000000000", "--out", tmp_path / "d")  # fmt: skip
    one_error(result, f"eval-views must be in 0..{MAX_EVAL_VIEWS}")
