"""``SOURCE_DATE_EPOCH``: the date written into what would otherwise carry today's (the
dataset card), so the same inputs give the same bytes (reproducible-builds.org's
convention: whole seconds since 1970-01-01 UTC, ASCII digits).

A value that is set but not that (milliseconds, a date string, a negative number) is
refused in one line before any work, not read as another date or ignored: the
convention asks a tool to fail on a malformed value. An empty value counts as unset.
"""

from __future__ import annotations

import os

from plantdreamer.errors import InputError

__all__ = ["source_date_epoch"]

NAME = "SOURCE_DATE_EPOCH"
LATEST = 253_402_300_799  # 9999-12-31 23:59:59 UTC: the last second a date can name


def source_date_epoch() -> int | None:
    """The seconds ``SOURCE_DATE_EPOCH`` gives, None when unset; InputError when malformed."""
    raw = os.environ.get(NAME, "")
    text = raw.strip()
    if not text:
        return None
    if not (text.isascii() and text.isdigit()):
        raise InputError(
            f"{NAME} must be whole seconds since 1970-01-01 UTC (digits only), got {raw!r}; "
            f"unset it to date the card by its plants"
        )
    seconds = int(text)
    if seconds > LATEST:
        raise InputError(
            f"{NAME}={text} is after the year 9999; it counts seconds, not milliseconds "
            f"({seconds // 1000} if this was milliseconds)"
        )
    return seconds
