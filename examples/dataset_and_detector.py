"""Make a small dataset with the Python API, then train a detector on it for a few
iterations: torchvision's Mask R-CNN on ``PlantViews``, the dataset as a torch Dataset.

    python examples/dataset_and_detector.py [OUT] [RAY_ADDRESS]

Plants run on worker processes of this machine, or on the Ray cluster at RAY_ADDRESS. The
settings here run in seconds on a CPU with no weights and no download (the detector starts
from random weights); the comments give what a real dataset uses.
"""

import sys

import torch
from torchvision.models.detection import MaskRCNN
from torchvision.models.detection.backbone_utils import resnet_fpn_backbone
from torchvision.models.detection.faster_rcnn import FastRCNNPredictor
from torchvision.models.detection.mask_rcnn import MaskRCNNHeads, MaskRCNNPredictor

import plantdreamer
from plantdreamer.data import PlantViews, collate

out = sys.argv[1] if len(sys.argv) > 1 else "example-dataset"
address = sys.argv[2] if len(sys.argv) > 2 else None

dataset = plantdreamer.make_dataset(
    out,
    species="bean",  # real: ["bean", "mint", "kale"], or a spec: make_dataset(out, "spec.toml")
    seeds="0-1",  # real: hundreds of plants per species, "0-499"
    plants_per_gpu=2,  # trained together in one worker; real: 8 to 16 on one GPU
    split="1,0,0",  # real: "0.8,0.1,0.1" (the default), whole plants per split
    address=address,  # None: this machine's cores and GPUs; "auto" or HOST:PORT: a Ray cluster
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
# Real: maskrcnn_resnet50_fpn(weights="DEFAULT") with its predictors made for
# views.num_classes, at 768 px for tens of epochs. Here a ResNet-18 and a light mask head
# (the full one costs a CPU seconds per iteration), from random weights: nothing to download.
backbone = resnet_fpn_backbone(backbone_name="resnet18", weights=None, trainable_layers=5)
model = MaskRCNN(
    backbone,
    min_size=64,
    max_size=64,
    box_batch_size_per_image=64,
    box_predictor=FastRCNNPredictor(1024, views.num_classes),
    mask_head=MaskRCNNHeads(256, [64], 1),
    mask_predictor=MaskRCNNPredictor(64, 64, views.num_classes),
)
optimizer = torch.optim.SGD(model.parameters(), lr=0.005, momentum=0.9)

torch.manual_seed(0)
model.train()
iterations = 2  # real: epochs over the whole train split
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
