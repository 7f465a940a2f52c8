"""``--help`` in sections: a click command whose options are listed under headings.

click has no option groups of its own; rich-click and click-option-group would add a
dependency for one formatter. A ``SectionedCommand`` takes ``sections`` (parameter name ->
heading) and lists its options heading by heading, in the order the headings first appear;
an option without one goes under ``other`` (``"help"`` names the help option). ``setting_sections`` derives the headings of a
config's settings from the section each belongs to (its first field), so a new setting
lands under its section with no edit here.
"""

from __future__ import annotations

from typing import Any

import click

from plantdreamer import settings

# GenerateConfig's sections (its fields holding nested configs) and their headings; the
# top-level settings (preset, seed) head the list.
SECTION_TITLES = {
    "": "Run",
    "source": "Input: species or point cloud",
    "init": "Initial Gaussians",
    "train": "Training",
    "sds": "Guidance (Stable Diffusion + depth ControlNet + LoRA)",
    "density": "Density control and culling",
    "outputs": "Outputs",
}


def setting_sections(cls: type, titles: dict[str, str] = SECTION_TITLES) -> dict[str, str]:
    """Parameter name -> heading for each setting of ``cls``, by the section it is in."""
    return {s.param: titles[s.path[0] if len(s.path) > 1 else ""] for s in settings.walk(cls)}


class SectionedCommand(click.Command):
    """A command whose ``--help`` lists its options under the headings of ``sections``."""

    def __init__(
        self, *args: Any, sections: dict[str, str] | None = None, other: str = "Other",
        **kwargs: Any,
    ) -> None:  # fmt: skip
        super().__init__(*args, **kwargs)
        self.sections = dict(sections or {})
        self.other = other

    def option_groups(self, ctx: click.Context) -> dict[str, list[tuple[str, str]]]:
        """Heading -> the help records (option, text) listed under it, in ``--help``'s
        order (the documentation's CLI reference lists them the same way)."""
        grouped: dict[str, list[tuple[str, str]]] = {}
        help_option = self.get_help_option(ctx)
        for param in self.get_params(ctx):
            record = param.get_help_record(ctx)
            if record is None:  # hidden, or an argument
                continue
            # click names its help option as it likes: "help" stands for it here.
            name = "help" if param is help_option else param.name or ""
            heading = self.sections.get(name, self.other)
            grouped.setdefault(heading, []).append(record)
        return grouped

    def format_options(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        for heading, records in self.option_groups(ctx).items():
            with formatter.section(heading):
                formatter.write_dl(records)
