"""Generate one plant with the Python API and list what it wrote.

    python examples/generate_plant.py [OUT]

The settings here run in seconds on a CPU and need no weights (no diffusion guidance); the
comments give what a real run uses. ``help(plantdreamer.generate)`` lists every setting, by
the same names as ``plantdreamer generate --help``.
"""

import sys

import plantdreamer

out = sys.argv[1] if len(sys.argv) > 1 else "example-plant"

[plant] = plantdreamer.generate(  # a list: one plant here, one per seed given seeds="0-3"
    out,
    species="bean",  # bean, mint or kale; or pointcloud="scan.ply" for a real plant
    seed=0,
    guidance="none",  # real: "sds" (the default): Stable Diffusion 2.1 + depth ControlNet
    # lora="lora/bean",  # real: the species LoRA (`plantdreamer info --check --lora ...`)
    points=2000,  # real: 100_000 (the default)
    steps=2,  # real: 3600 (the default), about 5 min per plant on one H200
    resolution=64,  # real: 768 on a GPU (the default there)
    eval_views=4,  # real: 120 (the default)
    turntable="none",  # real: "gif" (the default)
    overwrite=True,  # replace an earlier run in OUT
    quiet=True,  # real: a progress bar (the default)
)

print(f"{plant.ply}: {plant.gaussians} Gaussians, {plant.steps} steps in {plant.seconds:.1f} s")
print(f"{len(plant.renders)} renders, the first {plant.renders[0]}")
print(f"labels: {plant.coco} (COCO), {plant.folder / 'labels'} (class maps)")
print(f"progress pictures: {plant.progress}; loss plot: {plant.loss_plot or 'none (no guidance)'}")
print(f"every setting and timing: {plant.record}")
