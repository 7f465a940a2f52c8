"""Make a small dataset with the Python API, then train a detector on it for a few
iterations: torchvision's Mask R-CNN on ``PlantViews``, the dataset as a torch Dataset.

    python examples/dataset_and_detector.py [OUT] [RAY_ADDRESS]

Plants run on Ray: a local instance, or the cluster at RAY_ADDRESS. The settings here run in
seconds on a CPU with no weights and no download (the detector starts from random weights);
the comments give what a real dataset uses.
"""

import sys

import torch
from torchvision.models.detection import MaskRCNN
from torchvision.models.detection.backbone_utils import resnet_fpn_backbone

import plantdreamer
from plantdreamer.data import PlantViews, collate

out = sys.argv[1] if len(sys.argv) > 1 else "example-dataset"
address = sys.argv[2] if len(sys.argv) > 2 else None

dataset = plantdreamer.make_dataset(
    out,
    species="bean",  # real: "bean,mint,kale", or a spec file: make_dataset(out, "spec.toml")
    count=2,  # real: hundreds of plants per species
    split="1,0,0",  # real: "0.8,0.1,0.1" (the default), whole plants per split
    address=address,  # None: a local Ray; "auto" or HOST:PORT: a cluster
    guidance="none",  # real: "sds" (the default), with the weights and a LoRA per species
    points=2000,  # real: 100_000
    steps=2,  # real: 3600
    resolution=64,  # real: 768
    eval_views=2,  # real: 120 views per plant
    turntable="none",
    quiet=True,
)
print(f"{len(dataset.plants)} plants in {dataset.folder}; card: {dataset.card}")
print(f"COCO: {dataset.coco['train']}; YOLO: {dataset.yolo}")

views = PlantViews(dataset.folder, split="train")
loader = torch.utils.data.DataLoader(views, batch_size=2, shuffle=True, collate_fn=collate)
# Real: maskrcnn_resnet50_fpn(weights="DEFAULT") fine-tuned at 768 px for tens of epochs.
backbone = resnet_fpn_backbone(backbone_name="resnet18", weights=None, trainable_layers=5)
model = MaskRCNN(backbone, num_classes=views.num_classes, min_size=64, max_size=64)
optimizer = torch.optim.SGD(model.parameters(), lr=0.005, momentum=0.9)

torch.manual_seed(0)
model.train()
iterations = 3  # real: epochs over the whole train split
step = 0
while step < iterations:
    for images, targets in loader:
        losses = model(list(images), [{k: t[k] for k in ("boxes", "labels", "masks")}
                                      for t in targets])  # fmt: skip
        loss = sum(losses.values())
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        step += 1
        print(f"iteration {step}: loss {loss.item():.3f}")
        if step == iterations:
            break
