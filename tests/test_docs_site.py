"""The documentation site: its CLI reference says what `--help` says (real defaults, the
placeholders as written, whole summaries, generate's options under `--help`'s headings), its
API reference comes from the docstrings, and the built site reads whole in a browser.

The reference's Markdown is checked here through Python-Markdown as mkdocs renders it (fast);
the built site (`mkdocs build --strict`, several seconds) and headless Chromium are the slow
tier's.
"""

from __future__ import annotations

import functools
import html
import http.server
import re
import runpy
import subprocess
import sys
import threading
import time
from html.parser import HTMLParser
from pathlib import Path

import click
import pytest

from plantdreamer.cli import main

ROOT = Path(__file__).resolve().parent.parent
HOOK = ROOT / "scripts" / "docs_cli_reference.py"


BLOCKS = {"p", "td", "th", "tr", "li", "pre", "div", "table", "br", "h1", "h2", "h3", "h4", "dd"}


class PageText(HTMLParser):
    """A page's text (scripts and styles left out; blocks apart), its <p> paragraphs, and
    its headings."""

    def __init__(self) -> None:
        super().__init__()
        self.parts: list[str] = []
        self.paragraphs: list[str] = []
        self.headings: list[str] = []
        self._skip = 0
        self._open: list[tuple[str, list[str]]] = []

    def handle_starttag(self, tag: str, attrs: object) -> None:
        if tag in BLOCKS:
            self.parts.append(" ")
        if tag in ("script", "style"):
            self._skip += 1
        elif tag in ("p", "h2", "h3", "h4") and not self._skip:
            self._open.append((tag, []))

    def handle_endtag(self, tag: str) -> None:
        if tag in BLOCKS:
            self.parts.append(" ")
        if tag in ("script", "style"):
            self._skip -= 1
        elif self._open and self._open[-1][0] == tag:
            _, text = self._open.pop()
            joined = " ".join("".join(text).replace("\u00b6", "").split())  # toc's permalink
            (self.paragraphs if tag == "p" else self.headings).append(joined)

    def handle_data(self, data: str) -> None:
        if self._skip:
            return
        self.parts.append(data)
        for _, text in self._open:
            text.append(data)

    @property
    def text(self) -> str:
        return " ".join("".join(self.parts).split())


def page_text(markup: str) -> PageText:
    reader = PageText()
    reader.feed(markup)
    return reader


def normal(text: str) -> str:
    """Whitespace folded, and `quoted` spans as the page shows them (as code, unquoted)."""
    return " ".join(re.sub(r"`([^`]+)`", r"\1", text).split())


def every_command(
    command: click.Command, name: str, parent: click.Context | None = None
) -> list[tuple[click.Command, click.Context]]:
    """Each command of the CLI with its context, the group first."""
    ctx = click.Context(command, info_name=name, parent=parent, **command.context_settings)
    found = [(command, ctx)]
    if isinstance(command, click.Group):
        for sub in command.list_commands(ctx):
            found += every_command(command.get_command(ctx, sub), sub, ctx)  # type: ignore[arg-type]
    return found


def help_records(command: click.Command, ctx: click.Context) -> list[tuple[str, str]]:
    return [r for p in command.get_params(ctx) if (r := p.get_help_record(ctx)) is not None]


def help_headings(command: click.Command) -> list[str]:
    """The headings `--help` lists the options under, in its order."""
    text = command.get_help(click.Context(command, info_name="x"))
    return [line[:-1] for line in text.splitlines() if re.fullmatch(r"[A-Z][^ :].*:", line)]


def check_reference(text: PageText) -> None:
    """What a rendered CLI reference must hold (``text``: its page)."""
    assert "Sentinel" not in text.text and "UNSET" not in text.text
    assert "OUT/plants/<id>/" in text.text and "<species>-s<seed>" in text.text
    assert "//" not in text.text.replace("https://", "")  # no placeholder swallowed
    for command, ctx in every_command(main, "plantdreamer"):
        assert f"{ctx.command_path}" in text.headings, ctx.command_path
        for option, help_text in help_records(command, ctx):
            assert normal(option) in text.text, (ctx.command_path, option)
            assert normal(help_text) in text.text, (ctx.command_path, option)
        # Each summary whole (a generator that cuts it to a width ends it with "...").
        summary = normal(command.get_short_help_str(limit=1 << 20))
        assert summary in text.text and summary.endswith((".", ")")), summary
    generate = main.get_command(click.Context(main), "generate")
    assert generate is not None
    headings = help_headings(generate)
    assert len(headings) >= 6 and headings[0] == "Run"
    shown = re.findall(r"(?:^| )(" + "|".join(map(re.escape, headings)) + r") Option ", text.text)
    assert shown[: len(headings)] == headings  # generate's groups, in --help's order


def test_the_cli_reference_says_what_help_says():
    import markdown

    reference = runpy.run_path(str(HOOK))["reference"]()
    page = markdown.markdown(reference, extensions=["attr_list", "tables", "toc"])
    check_reference(page_text(page))


def test_the_reference_of_a_command_escapes_its_text_and_keeps_its_examples():
    hook = runpy.run_path(str(HOOK))

    @click.command(epilog="Examples:\n\n\b\n  tool --out <dir>\n  tool --x `y`")
    @click.option("--out", default="a|b", show_default=True, help="Into OUT/<id>/ (`<x>`).")
    def tool(out: str) -> None:
        """Make a *thing* <b>bold</b>: first sentence. Second one."""

    markup = hook["command_markdown"](tool, "tool")
    assert "OUT/&lt;id&gt;/ (<code>&lt;x&gt;</code>)" in markup
    assert "<pre><code>tool --out &lt;dir&gt;\ntool --x `y`</code></pre>" in markup
    assert "Make a *thing* &lt;b&gt;bold&lt;/b&gt;" in markup and "[default: a|b]" in markup


# --- the built site (slow tier) -------------------------------------------------------------


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    pytest.importorskip("mkdocs", reason="the docs extra is not installed (make docs)")
    pytest.importorskip("mkdocstrings", reason="the docs extra is not installed (make docs)")
    out = tmp_path_factory.mktemp("site")
    built = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    return out


def pages(site: Path) -> dict[str, str]:
    return {
        str(p.relative_to(site)): p.read_text(encoding="utf-8")
        for p in sorted(site.rglob("index.html"))
    }


@pytest.mark.slow
def test_the_built_site_has_whole_references_and_no_sentence_cut_short(site):
    built = pages(site)
    assert "cli/index.html" in built and "api/index.html" in built
    cut = []
    for name, markup in built.items():
        text = page_text(markup)
        assert "Sentinel" not in text.text, name
        if name.startswith(("api/", "cli/")):  # written from the code: checked below
            continue
        # Every paragraph of a page written by hand ends as a sentence or a label does.
        cut += [(name, p) for p in text.paragraphs if p and not p.endswith(ENDINGS)]
    assert not cut, "paragraphs cut short:\n" + "\n".join(f"{n}: {p[-120:]}" for n, p in cut)
    check_reference(page_text(built["cli/index.html"]))
    # The API reference: the functions and types a user imports, from their docstrings.
    api = page_text(built["api/index.html"])
    for name in ("plantdreamer.api.generate", "plantdreamer.api.make_dataset",
                 "plantdreamer.data.PlantViews", "plantdreamer.rasterizer.rasterization",
                 "plantdreamer.pipeline.settings.config.GenerateConfig", "ModelNotFoundError"):  # fmt: skip
        assert name in api.headings or any(h.startswith(name) for h in api.headings), name
    import plantdreamer.api

    first = normal(html.unescape(plantdreamer.api.make_dataset.__doc__ or "").split("\n\n")[0])
    assert normal(first.replace("``", "")) in api.text


ENDINGS = (".", ":", "!", "?", ")", '"')


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args: object) -> None:
        pass


def wait_for(browser, expression: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not browser.evaluate(expression):
        assert time.monotonic() < deadline, f"the page never had {expression}"
        time.sleep(0.1)


@pytest.mark.slow
def test_the_site_reads_whole_in_a_browser(site):
    from headless_browser import HeadlessChromium, find_chromium

    chromium = find_chromium()
    if chromium is None:
        pytest.skip("no Chromium: install Debian's chromium (make browser)")
    server = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(_Quiet, directory=str(site))
    )
    threading.Thread(target=server.serve_forever, daemon=True).start()
    address = f"http://127.0.0.1:{server.server_address[1]}"
    loaded = "document.readyState === 'complete' && location.pathname === '{}'"
    try:
        with HeadlessChromium(chromium, f"{address}/cli/", size=(1280, 900)) as browser:
            wait_for(browser, loaded.format("/cli/"))
            body = str(browser.evaluate("document.body.innerText"))
            assert "OUT/plants/<id>/" in body and "<species>-s<seed>" in body
            assert "Sentinel" not in body
            # Each option is a row of two cells, both laid out with room for their text.
            rows = browser.evaluate(
                "[...document.querySelectorAll('table.cli-options tbody tr')]"
                ".filter(tr => tr.cells.length === 2 && [...tr.cells].every("
                "td => td.getBoundingClientRect().width > 20)).length"
            )
            options = sum(
                len(help_records(c, ctx)) for c, ctx in every_command(main, "plantdreamer")
            )
            assert rows == options
            shot = browser.screenshot()
            assert shot.std() > 10  # a page drawn, not a blank one
            browser.evaluate(f"location.href = '{address}/api/'")
            wait_for(browser, loaded.format("/api/"))
            api = str(browser.evaluate("document.body.innerText"))
            assert "plantdreamer.api.generate" in api and "PlantViews" in api
    finally:
        server.shutdown()
        server.server_close()
