"""Species plants: valid meshes, documented traits over many seeds, determinism, errors."""

import io
import itertools
import os
import subprocess
import sys

import numpy as np
import pytest

from plantdreamer.errors import InputError
from plantdreamer.lsystem import OrganClass, generate_plant, grow, list_species

SEEDS = range(10)
SPECIES = list_species()  # every registered species gets the generic checks


@pytest.fixture(scope="module")
def plants():
    return {name: [grow(name, seed) for seed in SEEDS] for name in SPECIES}


def test_builtin_species_are_listed():
    assert {"bean", "kale", "mint"} <= set(list_species())
    assert list_species() == sorted(list_species())


def test_unknown_species_names_the_known_ones():
    with pytest.raises(InputError, match=r"unknown species 'oak'.*bean, bean-released, kale"):
        generate_plant("oak", 0)


@pytest.mark.parametrize("seed", [-1, 1.5, "3", True])
def test_bad_seed_is_an_input_error(seed):
    with pytest.raises(InputError, match="seed"):
        generate_plant("bean", seed)


@pytest.mark.parametrize("name", SPECIES)
def test_meshes_are_valid(plants, name):
    for plant in plants[name]:
        mesh = plant.mesh
        assert mesh.vertices.dtype == np.float32 and mesh.colors.dtype == np.float32
        assert mesh.faces.dtype == np.int64
        assert mesh.labels.dtype == np.int32 and mesh.instances.dtype == np.int32
        assert np.isfinite(mesh.vertices).all()
        assert mesh.colors.min() >= 0 and mesh.colors.max() <= 1
        areas, _ = mesh.face_areas_normals()
        assert areas.min() > 1e-10, "degenerate face"
        # A face belongs to one organ: its three vertices share label and instance.
        for per_vertex in (mesh.labels, mesh.instances):
            f = per_vertex[mesh.faces]
            assert (f == f[:, :1]).all()
        assert set(np.unique(mesh.labels)) == {int(c) for c in OrganClass}
        leaf = mesh.labels == OrganClass.LEAF
        assert (mesh.instances[leaf] >= 0).all() and (mesh.instances[~leaf] == -1).all()
        assert np.array_equal(np.unique(mesh.instances[leaf]), np.arange(len(plant.leaves)))
        # Consistent winding: no directed edge is used twice.
        f = mesh.faces
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        assert len(np.unique(edges, axis=0)) == len(edges)


@pytest.mark.parametrize("name", SPECIES)
def test_trimesh_agrees_the_winding_is_consistent(plants, name):
    tm = plants[name][0].mesh.to_trimesh()
    assert tm.is_winding_consistent
    assert len(tm.vertices) == len(plants[name][0].mesh.vertices)


@pytest.mark.parametrize("name", SPECIES)
def test_world_frame(plants, name):
    for plant in plants[name]:
        mesh = plant.mesh
        soil = mesh.vertices[mesh.labels == OrganClass.SOIL]
        np.testing.assert_allclose(soil[:, 2], 0.0)
        np.testing.assert_allclose(soil[:, :2].mean(axis=0), 0.0, atol=1e-6)
        pot = mesh.vertices[mesh.labels == OrganClass.POT]
        assert abs(pot[:, 0].max() + pot[:, 0].min()) < 1e-6
        plant_part = mesh.vertices[np.isin(mesh.labels, [OrganClass.LEAF, OrganClass.STEM])]
        assert plant_part[:, 2].min() > -0.02  # stems start just below the soil
        assert np.abs(plant_part[:, :2]).max() < 0.6


@pytest.mark.parametrize("name", SPECIES)
def test_leaf_front_faces_point_up_out_of_the_blade(plants, name):
    for plant in plants[name]:
        mesh = plant.mesh
        areas, normals = mesh.face_areas_normals()
        face_instance = mesh.instances[mesh.faces[:, 0]]
        for i, organ in enumerate(plant.leaves):
            mine = face_instance == i
            mean_normal = (normals[mine] * areas[mine, None]).sum(axis=0)
            assert mean_normal @ organ.up > 0, f"leaf {i} is upside down"
            # The blade starts at its insertion point.
            leaf_vertices = mesh.vertices[mesh.instances == i]
            assert np.linalg.norm(leaf_vertices - organ.position, axis=1).min() < 1e-5
        leaf = face_instance >= 0
        up_share = areas[leaf & (normals[:, 2] > 0)].sum() / areas[leaf].sum()
        assert up_share > 0.6


def plant_height(mesh):
    organs = np.isin(mesh.labels, [OrganClass.LEAF, OrganClass.STEM])
    return float(mesh.vertices[organs, 2].max())


@pytest.mark.parametrize("name", SPECIES)
def test_height_and_leaf_count_stay_in_the_documented_ranges(plants, name):
    species = plants[name][0].species
    heights = [plant_height(p.mesh) for p in plants[name]]
    leaves = [p.mesh.n_leaves for p in plants[name]]
    lo, hi = species.height_range
    assert lo <= min(heights) and max(heights) <= hi, heights
    lo, hi = species.leaf_range
    assert lo <= min(leaves) and max(leaves) <= hi, leaves


def test_different_seeds_give_different_plants(plants):
    for name in SPECIES:
        first = [p.mesh for p in plants[name][:3]]
        assert len({round(plant_height(m), 6) for m in first}) == 3
        plant_parts = [m.vertices[m.labels <= OrganClass.STEM] for m in first]
        assert plant_parts[0].shape != plant_parts[1].shape or not np.allclose(*plant_parts[:2])


def by_chain(leaves):
    groups = {}
    for leaf in leaves:
        groups.setdefault(leaf.chain, []).append(leaf)
    return groups


def test_bean_leaves_are_trifoliate(plants):
    for plant in plants["bean"]:
        chains = plant.skeleton.chains
        groups = by_chain(plant.leaves)
        assert len(groups) >= 7  # at least the authors' 7 main-stem nodes
        for chain, leaflets in groups.items():
            assert len(leaflets) == 3
            assert chains[chain].parent >= 0  # a petiole growing from a stem
            lateral, other, terminal = leaflets
            # Lateral leaflets face each other across the rachis; the terminal one is beyond.
            np.testing.assert_allclose(lateral.position, other.position)
            assert lateral.heading @ other.heading < 0.2
            assert np.linalg.norm(terminal.position - lateral.position) > 1e-3
            assert terminal.params[0] > lateral.params[0]


def test_bean_main_stem_is_upright_and_leaves_alternate(plants):
    for plant in plants["bean"]:
        stem = plant.skeleton.chains[0].points
        assert stem[-1, 2] > 0.15
        lean = np.linalg.norm(stem[-1, :2] - stem[0, :2]) / (stem[-1, 2] - stem[0, 2])
        assert lean < 0.5
        chains = plant.skeleton.chains
        petioles = sorted({leaf.chain for leaf in plant.leaves if chains[leaf.chain].parent == 0})
        steps = [chains[c].points[-1, :2] - chains[c].points[0, :2] for c in petioles]
        azimuths = [np.arctan2(d[1], d[0]) for d in steps]
        turns = np.degrees(np.abs(np.angle(np.exp(1j * np.diff(azimuths)))))
        assert np.median(turns) > 80  # successive leaves point to different sides


def mint_pairs(plant):
    """Leaves grouped by the point their petiole leaves the stem."""
    chains = plant.skeleton.chains
    pairs = {}
    for leaf in plant.leaves:
        start = tuple(np.round(chains[leaf.chain].points[0], 9))
        pairs.setdefault((chains[leaf.chain].parent, start), []).append(leaf)
    return pairs, chains


def test_mint_has_3_to_7_square_stems_with_opposite_decussate_leaves(plants):
    stem_counts = []
    for plant in plants["mint"]:
        pairs, chains = mint_pairs(plant)
        stems = [i for i, c in enumerate(chains) if c.parent == -1]
        stem_counts.append(len(stems))
        assert 3 <= len(stems) <= 7
        assert plant.species.stem_sides == 4
        for stem in stems:
            nodes = [(k, v) for k, v in pairs.items() if k[0] == stem]
            nodes.sort(key=lambda kv: kv[0][1][2])
            assert len(nodes) >= 4
            directions = []
            for (_, start), leaves in nodes:
                assert len(leaves) == 2, "mint leaves come in opposite pairs"
                # A node ends an internode: the stem's direction there is from the point before.
                axis = chains[stem].points
                tangent = start - axis[np.argmin(np.linalg.norm(axis - start, axis=1)) - 1]
                tangent /= np.linalg.norm(tangent)
                d = [c.points[-1] - c.points[0] for c in (chains[leaf.chain] for leaf in leaves)]
                d = [x - tangent * (x @ tangent) for x in d]
                d = [x / np.linalg.norm(x) for x in d]
                assert d[0] @ d[1] < -0.8  # opposite
                directions.append(d[0])
            # Decussate: each pair is roughly perpendicular to the previous one.
            for a, b in itertools.pairwise(directions):
                assert abs(a @ b) < 0.5
            sizes = [max(leaf.params[0] for leaf in leaves) for _, leaves in nodes]
            assert sizes[-1] < 0.6 * max(sizes)  # shrinking towards the top
    assert len(set(stem_counts)) > 1  # the number of stems varies between seeds


def test_kale_is_a_rosette_of_diminishing_leaves(plants):
    for plant in plants["kale"]:
        chains = plant.skeleton.chains
        height = plant_height(plant.mesh)
        sizes = []
        for leaf in plant.leaves:
            petiole = chains[leaf.chain]
            base = petiole.points[0]
            assert base[2] < 0.3 * height  # leaves originate near the base
            assert np.hypot(*base[:2]) < 0.02
            assert petiole.parent == 0
            assert np.linalg.norm(leaf.position - base) > 0.3 * leaf.params[0]  # long petiole
            sizes.append(leaf.params[0])
        sizes = np.array(sizes)
        assert sizes[0] > 3 * sizes[-1]
        assert (np.diff(sizes) < 0).mean() > 0.7


def test_same_seed_gives_identical_meshes_and_files(tmp_path):
    a = generate_plant("mint", 7)
    b = generate_plant("mint", 7)
    for field in ("vertices", "faces", "colors", "labels", "instances"):
        assert np.array_equal(getattr(a, field), getattr(b, field))
    glb = [io.BytesIO(), io.BytesIO()]
    a.to_trimesh().export(glb[0], file_type="glb")
    b.to_trimesh().export(glb[1], file_type="glb")
    assert glb[0].getvalue() == glb[1].getvalue()


def test_same_seed_gives_the_same_plant_in_other_processes():
    # Fresh interpreters with different hash seeds: no dict/set ordering may leak in.
    code = (
        "import hashlib; from plantdreamer.lsystem import generate_plant, sample_points;"
        "m = generate_plant('bean', 11); c = sample_points(m, 2000, seed=4);"
        "h = hashlib.sha256();"
        "[h.update(a.tobytes()) for a in (m.vertices, m.faces, m.colors, m.labels, m.instances,"
        " c.positions, c.colors, c.normals, c.attributes['label'], c.attributes['instance'])];"
        "print(h.hexdigest())"
    )
    digests = {
        subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            check=True,
            env={**os.environ, "PYTHONHASHSEED": str(hash_seed)},
        ).stdout.strip()
        for hash_seed in (1, 2)
    }
    assert len(digests) == 1
