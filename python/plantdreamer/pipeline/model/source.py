"""The run's input as a normalised point cloud: an L-System plant or a prepared capture."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantdreamer import prepare
from plantdreamer.cloud import PointCloud
from plantdreamer.errors import InputError
from plantdreamer.gaussians import Gaussians
from plantdreamer.labels import NO_INSTANCE, as_int_labels, find_label_fields
from plantdreamer.pipeline.model.init import InitConfig, init_gaussians, initial_colors
from plantdreamer.pointcloud import NormalizeTransform
from plantdreamer.settings import setting

STRUCTURES = ("plantdreamer", "released")  # species grammars: ours or the authors'
# The full-grown stage (``lsystem.growth.FULL_GROWN``, which the settings' module may not
# import: the command line reads it at start-up, before anything heavy; a test holds the
# two equal).
FULL_GROWN = 1.0


# Scene sizes the fixed camera planes hold: below 0.1 the framed cameras come within the
# near plane of the plant (clipped renders), and far above 1e6 float32 positions lose the
# plant's detail (renders, labels and COCO empty).
SCENE_SIZES = (0.1, 1e6)


@dataclass
class SourceConfig:
    """The input section: a point cloud (PLY), or else the species' L-System. With a point
    cloud, species only names the plant in the prompts."""

    species: str | None = setting(
        None,
        "L-System species to generate (see `plantdreamer lsystem --list`); with "
        "--pointcloud, the plant named in the prompts.",
    )
    structures: str = setting(
        "plantdreamer",
        "Which grammar a species name grows: ours, or the authors' released structure "
        "(bean -> bean-released).",
        choices=STRUCTURES,
    )
    growth: float = setting(
        FULL_GROWN,
        "Growth stage of the L-System plant in (0, 1]: the fraction of its derivation "
        "steps (1: full-grown); a leaf keeps its id, insertion point and growing size at "
        "every stage (docs/traits.md).",
        range=(0.0, FULL_GROWN),
        open=(True, False),
    )
    growth_since: float | None = setting(
        None,
        "An earlier growth stage: traits.json marks the leaves that emerged after it as "
        "new (a dataset's growth series gives each stage the one before it).",
        range=(0.0, FULL_GROWN),
        open=(True, True),
    )
    pointcloud: str | None = setting(None, "A real plant point cloud (PLY).")
    points: int = setting(
        prepare.TARGET_POINTS, "Points to start from (0: every point of a --pointcloud)."
    )
    sor_neighbors: int = setting(
        prepare.SOR_NEIGHBORS, "Statistical outlier removal: neighbours per point."
    )
    sor_std: float = setting(prepare.SOR_STD, "Statistical outlier removal: std multiplier.")
    scene_size: float = setting(
        4.0,
        "Longest side of the normalised scene (the rasterizer's near and far planes, 0.01 "
        "and 1e10 scene units, hold a framed scene of this size).",
        range=SCENE_SIZES,
    )
    sor_after_voxel: bool = setting(False, "Capture prep: outlier removal after the voxel grid.")
    downsample_tolerance: float = setting(
        prepare.TOLERANCE,
        "Capture prep: voxel downsampling aims at --points +- this fraction; clouds below "
        "(1 + this) x --points are kept whole (released: 0.25).",
    )
    mesh_sor: bool = setting(False, "Outlier removal on L-System mesh samples too.")
    label_field: str | None = setting(
        None,
        "Point-cloud property with class ids.",
        default_text="label, class, scalar_Classification, semantic, ... if present",
    )
    instance_field: str | None = setting(
        None,
        "Point-cloud property with instance ids.",
        default_text="instance, instance_id, leaf_id, ... if present",
    )

    def validate(self) -> None:
        """A growth stage is the L-System's, and a stage's earlier one comes before it."""
        if self.pointcloud is not None and self.growth != FULL_GROWN:
            raise InputError("growth is a stage of an L-System plant; a point cloud is as captured")
        if self.growth_since is not None and not self.growth_since < self.growth:
            raise InputError(
                f"growth-since {self.growth_since:g} must be an earlier stage than growth "
                f"{self.growth:g}"
            )

    def structure(self) -> str | None:
        """The registered species the L-System input grows (``structures`` applied)."""
        from plantdreamer.lsystem.species import structure_for

        return None if self.species is None else structure_for(self.species, self.structures)

    def plant_name(self) -> str:
        """The plant's name in the prompts (``bean`` for ``bean-released``)."""
        from plantdreamer.lsystem.species import plant_name

        return "plant" if self.species is None else plant_name(self.species)


@dataclass
class Source:
    points: np.ndarray  # [N, 3] float32, normalised (centred, longest side = scene_size)
    colors: np.ndarray | None  # [N, 3] float32 in [0, 1]
    transform: NormalizeTransform  # restores the input frame at export
    counts: dict[str, int]  # points after each preparation step, for run.json
    labels: np.ndarray | None = None  # [N, 2] int32 (label, instance), -1 where none
    label_fields: dict[str, str | None] | None = None  # the input properties they came from
    normals: np.ndarray | None = None  # [N, 3] surface normals (L-System faces), else None
    boundary_distance: np.ndarray | None = None  # [N] to the surface's edge (L-System), scaled
    captured: bool = False  # a point cloud (True) or an L-System mesh's samples


def load_source(src: SourceConfig, seed: int, *, surface: bool) -> Source:
    """A captured cloud goes through `prepare_cloud` (finite, SOR, voxel to ~points,
    normalise); an L-System mesh is sampled uniformly by area (then, with ``mesh_sor``,
    filtered by SOR as the released code does), then normalised. Labels come with the points:
    the L-System's organ and leaf ids, or a cloud's label properties. ``surface``: the
    L-System samples keep their normals and distances to the surface's edge (the init
    section's surface-aligned Gaussians)."""
    from plantdreamer.pointcloud import normalize

    if src.pointcloud is not None:
        from plantdreamer.io import read_ply

        raw = read_ply(Path(src.pointcloud))
        fields = find_label_fields(raw.attributes, src.label_field, src.instance_field)
        for name in fields:
            if name is not None:  # check the values before the slow steps
                raw.attributes[name] = as_int_labels(name, raw.attributes[name])
        cloud, transform, report = prepare.prepare_cloud(
            raw,
            target=src.points or None,  # 0: no downsampling, as `prepare --points 0`
            sor_neighbors=src.sor_neighbors,
            sor_std=src.sor_std,
            normalize_size=src.scene_size,
            sor_after_voxel=src.sor_after_voxel,
            tolerance=src.downsample_tolerance,
            label_fields=[n for n in fields if n is not None],
        )
        assert transform is not None
        return Source(
            cloud.positions.astype(np.float32),
            cloud.colors,
            transform,
            dict(report.counts),
            _labels(cloud, *fields),
            {"label": fields[0], "instance": fields[1]},
            captured=True,
        )

    from plantdreamer.lsystem import generate_plant, sample_points

    species = src.structure()  # the registered species grown (``structures`` applied)
    if species is None:
        raise InputError("give an input: a species (L-System) or a point cloud")
    cloud = sample_points(
        generate_plant(species, seed, src.growth), src.points, seed, boundary_distance=surface
    )
    counts = {"sampled": len(cloud)}
    if src.mesh_sor:
        from plantdreamer.pointcloud import remove_statistical_outliers

        cloud = cloud.subset(
            remove_statistical_outliers(cloud.positions, src.sor_neighbors, src.sor_std)
        )
        counts["outliers removed"] = len(cloud)
    points, transform = normalize(cloud.positions, size=src.scene_size)
    return Source(
        points.astype(np.float32),
        cloud.colors,
        transform,
        counts,
        _labels(cloud, "label", "instance"),
        {"label": "OrganClass", "instance": "leaf"},
        cloud.normals if surface else None,  # normalising scales: directions unchanged
        cloud.attributes["boundary_distance"] * np.float32(transform.scale) if surface else None,
    )


def initial_gaussians(init: InitConfig, source: Source, seed: int) -> Gaussians:
    """The Gaussians a run starts from: one per source point, by the init section's rules."""
    rng = np.random.default_rng([seed, 0xC0102])
    colors = initial_colors(source.colors, len(source.points), init.color_init, rng)
    return init_gaussians(
        source.points,
        colors,
        init.opacity(source.captured),
        init.sh_degree,
        scale_rule=init.init_scale,
        labels=source.labels,
        normals=source.normals,
        boundary_distance=source.boundary_distance,
    )


def _labels(cloud: PointCloud, label: str | None, instance: str | None) -> np.ndarray | None:
    if label is None and instance is None:
        return None
    out = np.full((len(cloud), 2), NO_INSTANCE, dtype=np.int32)
    for i, name in enumerate((label, instance)):
        if name is not None:
            out[:, i] = as_int_labels(name, cloud.attributes[name])
    return out
