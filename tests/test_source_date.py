"""A malformed ``SOURCE_DATE_EPOCH`` (milliseconds, a date string) is refused in one line
before any plant runs, never read as another date and never an internal error after the
work."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from cli_run import one_error
from plantdreamer.cli import main
from plantdreamer.errors import InputError
from plantdreamer.exports.card import made_on
from plantdreamer.source_date import source_date_epoch

MALFORMED = ["1700000000000", "2024-01-01", "-5", "1.7e9", "17e8"]


@pytest.mark.parametrize("value", MALFORMED)
def test_a_malformed_value_is_refused(monkeypatch, value):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", value)
    with pytest.raises(InputError, match="SOURCE_DATE_EPOCH"):
        source_date_epoch()
    with pytest.raises(InputError, match="SOURCE_DATE_EPOCH"):
        made_on([])


def test_seconds_date_the_card_and_empty_is_unset(monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    assert made_on([]) == "2023-11-14"
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "253402300799")
    assert made_on([]) == "9999-12-31"
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "")
    assert source_date_epoch() is None


def test_dataset_refuses_milliseconds_before_any_plant(monkeypatch, tmp_path):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000000")
    out = tmp_path / "ds"
    result = CliRunner().invoke(main, ["dataset", "--species", "bean", "--guidance", "none",
                                       "--dry-run", "--allow-empty-split", "--out", str(out)])  # fmt: skip
    one_error(result, "milliseconds")
    assert not out.exists()


def test_labels_refuses_milliseconds_before_anything(monkeypatch, tmp_path):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000000")
    (tmp_path / "plants").mkdir()
    one_error(CliRunner().invoke(main, ["labels", str(tmp_path)]), "milliseconds")
    assert [p.name for p in tmp_path.iterdir()] == ["plants"]
