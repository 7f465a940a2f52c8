"""The documentation site's command-line reference, written from the click commands.

A mkdocs hook (mkdocs.yml's ``hooks:``): in a page holding ``<!-- cli-reference -->`` it puts
each command's usage, its whole help text and its options with the text ``--help`` prints
for them (click's own help records: the defaults, choices and placeholders as a user sees
them), generate's under the same headings as its ``--help``, and each group's commands
with their whole first sentence. The text is escaped as HTML, so that ``<id>`` or
``<species>-s<seed>`` shows as written; a `quoted` span becomes code, as in the docstrings.

Run alone, it prints the Markdown it would insert: ``python scripts/docs_cli_reference.py``.
"""

from __future__ import annotations

import html
import re
from typing import Any

import click

MARKER = "<!-- cli-reference -->"
PROGRAM = "plantdreamer"
_CODE_SPAN = re.compile(r"`([^`]+)`")


def inline(text: str) -> str:
    """``text`` as HTML: escaped, with `quoted` spans as code."""
    parts = _CODE_SPAN.split(text)
    return "".join(
        f"<code>{html.escape(part)}</code>" if i % 2 else html.escape(part)
        for i, part in enumerate(parts)
    )


def paragraphs(text: str) -> str:
    """Help text as click lays it out: paragraphs rewrapped, except those that start with
    a ``\\b`` line, which keep their lines (examples, lists)."""
    out = []
    for block in re.split(r"\n\s*\n", text.strip("\n")):
        lines = block.splitlines()
        if lines and lines[0].strip() == "\b":
            kept = "\n".join(line.rstrip() for line in lines[1:])
            out.append(f"<pre><code>{html.escape(_dedent(kept))}</code></pre>")
        elif block.strip():
            out.append(f"<p>{inline(' '.join(block.split()))}</p>")
    return "\n".join(out)


def _dedent(text: str) -> str:
    import textwrap

    return textwrap.dedent(text)


def help_text(command: click.Command) -> str:
    """The help click prints for ``command`` (up to a ``\\f``), its docstring cleaned."""
    import inspect

    return inspect.cleandoc(command.help or "").partition("\f")[0]


def option_groups(command: click.Command, ctx: click.Context) -> dict[str, list[tuple[str, str]]]:
    """Heading -> (option, text) as ``--help`` lists them."""
    grouped = getattr(command, "option_groups", None)
    if grouped is not None:
        return dict(grouped(ctx))
    records = [r for p in command.get_params(ctx) if (r := p.get_help_record(ctx)) is not None]
    return {"Options": records} if records else {}


def option_table(records: list[tuple[str, str]]) -> str:
    rows = "\n".join(
        f"<tr><td><code>{html.escape(option)}</code></td><td>{inline(' '.join(text.split()))}"
        "</td></tr>"
        for option, text in records
    )
    return (
        '<table class="cli-options">\n<thead><tr><th>Option</th><th>What it does</th></tr>'
        f"</thead>\n<tbody>\n{rows}\n</tbody>\n</table>"
    )


def anchor(path: str) -> str:
    """The heading's id as mkdocs' table of contents makes it (toc's default slugify)."""
    from markdown.extensions.toc import slugify

    return str(slugify(path, "-"))


def commands_of(group: click.Group, ctx: click.Context) -> list[tuple[str, click.Command]]:
    found = [(n, group.get_command(ctx, n)) for n in group.list_commands(ctx)]
    return [(n, c) for n, c in found if c is not None and not c.hidden]


def command_markdown(
    command: click.Command, name: str, parent: click.Context | None = None, level: int = 2
) -> str:
    """Markdown of ``command`` and, for a group, of each of its commands below it."""
    ctx = click.Context(command, info_name=name, parent=parent, **command.context_settings)
    path = ctx.command_path
    usage = " ".join([path, *command.collect_usage_pieces(ctx)])
    parts = [f"{'#' * level} {path}", "", f"<pre><code>{html.escape(usage)}</code></pre>"]
    parts.append(paragraphs(help_text(command)))
    for heading, records in option_groups(command, ctx).items():
        parts.append(f'<p class="cli-group"><strong>{html.escape(heading)}</strong></p>')
        parts.append(option_table(records))
    subcommands: list[tuple[str, click.Command]] = []
    if isinstance(command, click.Group):
        subcommands = commands_of(command, ctx)
        rows = "\n".join(
            f'<tr><td><a href="#{anchor(f"{path} {n}")}"><code>{html.escape(n)}</code></a>'
            f"</td><td>{inline(c.get_short_help_str(limit=1 << 20))}</td></tr>"
            for n, c in subcommands
        )
        parts.append('<p class="cli-group"><strong>Commands</strong></p>')
        parts.append(
            '<table class="cli-commands">\n<thead><tr><th>Command</th><th>What it does</th>'
            f"</tr></thead>\n<tbody>\n{rows}\n</tbody>\n</table>"
        )
    if command.epilog:
        parts.append(paragraphs(inspect_epilog(command.epilog)))
    text = "\n\n".join(p for p in parts if p) + "\n"
    for n, c in subcommands:
        text += "\n" + command_markdown(c, n, ctx, level if parent is None else level + 1)
    return text


def inspect_epilog(epilog: str) -> str:
    import inspect

    return inspect.cleandoc(epilog)


def reference() -> str:
    """The whole reference: ``plantdreamer`` and every command under it."""
    from plantdreamer.cli import main

    return command_markdown(main, PROGRAM)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any, **kwargs: Any) -> str:
    """mkdocs' hook: the reference in place of the marker."""
    return markdown.replace(MARKER, reference()) if MARKER in markdown else markdown


if __name__ == "__main__":
    print(reference())
