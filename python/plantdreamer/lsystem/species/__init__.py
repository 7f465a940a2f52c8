"""The species registry. Adding a species: write ``species/<name>.py`` defining ``SPECIES``
(a ``Species``), then add it to ``_BUILTIN`` below (or call ``register`` at run time)."""

from __future__ import annotations

from plantdreamer.errors import InputError
from plantdreamer.lsystem.species import bean, kale, mint, released
from plantdreamer.lsystem.species.base import Species

__all__ = [
    "Species",
    "get_species",
    "list_species",
    "plant_name",
    "register",
    "structure_for",
    "unknown_species",
]

# Ours, then the authors' released structures (bean-released, mint-released, kale-released).
_BUILTIN = (bean.SPECIES, kale.SPECIES, mint.SPECIES, *released.SPECIES)
_REGISTRY: dict[str, Species] = {s.name: s for s in _BUILTIN}


def register(species: Species) -> None:
    """Makes ``species`` available to ``generate_plant`` and the CLI under its name."""
    if not species.name or not species.name.replace("-", "_").isidentifier():
        raise InputError(f"species name must be an identifier (or with '-'), got {species.name!r}")
    _REGISTRY[species.name] = species


def list_species() -> list[str]:
    """Names of the registered species, sorted."""
    return sorted(_REGISTRY)


def get_species(name: str) -> Species:
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise unknown_species(name) from None


def unknown_species(name: object) -> InputError:
    """The error for a species that is not registered: the closest name ("did you mean")
    when there is one, and every known name."""
    import difflib

    known = list_species()
    close = difflib.get_close_matches(str(name), known, n=1) if isinstance(name, str) else []
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return InputError(f"unknown species {name!r}{hint}; known: {', '.join(known)}")


def structure_for(name: str, structures: str = "plantdreamer") -> str:
    """The species to grow for ``name``: with ``structures="released"``, the authors'
    structure of that plant (``bean`` -> ``bean-released``) where one is registered."""
    if structures == "released" and f"{name}-released" in _REGISTRY:
        return f"{name}-released"
    return name


def plant_name(name: str) -> str:
    """What prompts call the plant ``name``: a registered species' prompt name (``bean`` for
    ``bean-released``), else ``name`` itself (the plant of a point cloud)."""
    species = _REGISTRY.get(name)
    return species.plant_name if species is not None else name
