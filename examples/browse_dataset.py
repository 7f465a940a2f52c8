"""Browse a dataset (or one plant folder) with ``PlantViews``: its classes and views, and
one view drawn beside its class map and objects.

    python examples/browse_dataset.py DATASET [PICTURE]

DATASET is a folder made by ``plantdreamer dataset`` (or ``make_dataset``), or a plant
folder made by ``generate``; PICTURE (default ``browse.png``) is where the drawing goes.
"""

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from plantdreamer.data import PlantViews

folder = sys.argv[1]
picture = sys.argv[2] if len(sys.argv) > 2 else "browse.png"

views = PlantViews(folder)  # a dataset's split: PlantViews(folder, split="train")
print(f"{len(views)} views; classes {views.classes} (0 is background)")

image, target = views[0]
print(f"view 0 ({views.describe(0)}): {len(target['boxes'])} objects, labels "
      f"{target['labels'].tolist()}, {int(target['ignore'].sum())} ignored pixels")  # fmt: skip

figure, axes = plt.subplots(1, 3, figsize=(9, 3))
axes[0].imshow(image.permute(1, 2, 0).numpy())
axes[0].set_title("render")
axes[1].imshow(target["semantic"].numpy(), cmap="tab10", vmin=0, vmax=9, interpolation="nearest")
axes[1].set_title("classes")
axes[2].imshow(image.permute(1, 2, 0).numpy())
for x0, y0, x1, y1 in target["boxes"].tolist():
    axes[2].add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, color="yellow"))
axes[2].set_title("objects")
for ax in axes:
    ax.axis("off")
figure.tight_layout()
figure.savefig(picture)
print(f"drawn: {picture}")
