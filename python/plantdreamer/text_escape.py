"""User-given text (a species or class name, a model folder's name) made safe where a
record is written for people: one line, and inert in Markdown and HTML.

A dataset card is Markdown that a hub renders as HTML: a name holding ``|`` would split a
table's row, a newline would start a heading or a licence line, ``<script>`` would be HTML.
``markdown_text`` keeps the characters and removes their meaning; ``one_line`` only folds
the whitespace, for fields that a serialiser quotes itself (YAML through its dumper, JSON).
"""

from __future__ import annotations

import html
import re

# The ASCII punctuation marks that Markdown (CommonMark, GFM's tables and autolinks, the
# Hub's math and emoji) may read as syntax; in CommonMark a backslash before any ASCII
# punctuation mark shows the mark itself.
_MARKDOWN_MARKS = re.compile(r"([\\`*_{}\[\]()#+\-.!|~:$])")
_CONTROL = re.compile(r"[\x00-\x1f\x7f\u2028\u2029]")


def one_line(text: object) -> str:
    """``text`` as one line: every run of whitespace or control characters one space."""
    return " ".join(_CONTROL.sub(" ", str(text)).split())


def html_text(text: object) -> str:
    """``text`` as HTML text: one line, ``& < > " '`` as entities."""
    return html.escape(one_line(text), quote=True)


def markdown_text(text: object) -> str:
    """``text`` as Markdown inline text that renders as itself (CommonMark, GFM): one
    line, Markdown's marks escaped with a backslash (tables' ``|``, emphasis, links, math),
    then HTML's ``& < >`` as entities."""
    return html.escape(_MARKDOWN_MARKS.sub(r"\\\1", one_line(text)), quote=False)
