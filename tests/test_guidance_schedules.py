"""Timestep schedules: stage boundaries, integer ranges, sampling, scaling, the clamp ramp."""

import pytest
import torch

from plantdreamer.errors import InputError
from plantdreamer.guidance.schedules import (
    TimestepSchedule,
    make_schedule,
    paper_schedule,
    parse_schedule,
    ramp,
    released_code_schedule,
)


@pytest.mark.parametrize(
    ("step", "bounds"),
    [
        (0, (200, 980)),
        (599, (200, 980)),
        (600, (120, 350)),
        (999, (120, 350)),
        (1000, (120, 250)),
        (1999, (120, 250)),
        (2000, (75, 150)),
        (3599, (75, 150)),
        (100_000, (75, 150)),
    ],
)
def test_paper_schedule_boundaries(step, bounds):
    assert paper_schedule().bounds(step) == bounds


@pytest.mark.parametrize(
    ("step", "bounds"), [(0, (20, 980)), (500, (20, 980)), (501, (20, 550)), (3599, (20, 550))]
)
def test_released_code_schedule_boundaries(step, bounds):
    assert released_code_schedule().bounds(step) == bounds


def test_samples_cover_the_inclusive_range_and_nothing_else():
    schedule = TimestepSchedule([(None, 0.1, 0.105)])  # timesteps 100..105
    rng = torch.Generator().manual_seed(0)
    t = schedule.sample_timestep(0, rng, batch_size=2000)
    assert t.dtype == torch.long
    assert set(t.tolist()) == set(range(100, 106))


def test_sampling_is_reproducible_from_the_seed():
    s = paper_schedule()
    a = s.sample_timestep(10, torch.Generator().manual_seed(3), batch_size=8)
    b = s.sample_timestep(10, torch.Generator().manual_seed(3), batch_size=8)
    c = s.sample_timestep(10, torch.Generator().manual_seed(4), batch_size=8)
    assert torch.equal(a, b)
    assert not torch.equal(a, c)


def test_max_fraction_one_stays_a_valid_timestep():
    assert TimestepSchedule([(None, 0.0, 1.0)]).bounds(0) == (0, 999)


def test_builtin_schedule_scales_with_run_length():
    half = make_schedule("paper", total_steps=1800)
    assert [s.until_step for s in half.stages] == [300, 500, 1000, None]
    assert half.bounds(299) == (200, 980)
    assert half.bounds(300) == (120, 350)
    assert make_schedule("paper", total_steps=3600) == paper_schedule()
    # Very short runs keep strictly increasing boundaries.
    tiny = make_schedule("paper", total_steps=2)
    assert [s.until_step for s in tiny.stages] == [1, 2, 3, None]


def test_user_table_is_parsed_and_used_as_written():
    s = make_schedule("0.3-0.9@10,0.1-0.2", total_steps=1800)
    assert s.bounds(9) == (300, 900)
    assert s.bounds(10) == (100, 200)
    assert parse_schedule(" 0.5-0.6 ").bounds(7) == (500, 600)
    assert make_schedule([(5, 0.2, 0.3), (None, 0.1, 0.1)]).bounds(5) == (100, 100)


@pytest.mark.parametrize(
    "bad",
    [
        "0.3-0.2",  # min > max
        "0.1-1.5",  # above 1
        "0.2-0.9@100,0.1-0.2@50,0.1-0.1",  # boundaries not increasing
        "0.2-0.9@100",  # last stage not open-ended
        "0.2-0.9,0.1-0.2",  # open-ended stage before the last
        "0.2@100,0.1-0.2",  # no max
        "fast",  # unknown name
    ],
)
def test_bad_tables_are_input_errors(bad):
    with pytest.raises(InputError):
        make_schedule(bad)


def test_negative_step_is_rejected():
    with pytest.raises(InputError):
        paper_schedule().bounds(-1)


def test_grad_clip_ramp_rises_from_1_5_to_2_over_1000_steps():
    assert ramp(0, 0, 1.5, 2.0, 1000) == 1.5
    assert ramp(500, 0, 1.5, 2.0, 1000) == pytest.approx(1.75)
    assert ramp(1000, 0, 1.5, 2.0, 1000) == 2.0
    assert ramp(3599, 0, 1.5, 2.0, 1000) == 2.0
    assert ramp(5, 10, 1.0, 3.0, 10) == 1.0  # degenerate ramp: a step function
