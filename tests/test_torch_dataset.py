"""``plantdreamer.data.PlantViews``: torchvision-ready items, and one Mask R-CNN training step."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from plantdreamer.data import PlantViews, collate
from plantdreamer.errors import InputError

torchvision = pytest.importorskip("torchvision")


def test_items_have_the_dtypes_detection_models_take(bean):
    from torchvision import tv_tensors

    data = PlantViews(bean)
    assert len(data) == 3 and data.num_classes == 5
    assert data.classes == {1: "leaf", 2: "stem", 3: "pot", 4: "soil"}
    for i in range(len(data)):
        image, target = data[i]
        assert isinstance(image, tv_tensors.Image) and image.dtype == torch.float32
        assert image.shape == (3, 96, 96) and 0 <= image.min() and image.max() <= 1
        boxes, masks = target["boxes"], target["masks"]
        assert isinstance(boxes, tv_tensors.BoundingBoxes) and boxes.format.name == "XYXY"
        assert isinstance(masks, tv_tensors.Mask) and masks.dtype == torch.uint8
        assert target["labels"].dtype == torch.int64 and target["semantic"].dtype == torch.int64
        k = len(target["labels"])
        assert boxes.shape == (k, 4) and masks.shape == (k, 96, 96)
        assert ((boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])).all()
        assert (target["area"] >= 16).all()
        assert torch.equal(target["area"], masks.flatten(1).sum(1).float())
        # Each box is its mask's pixel-edge box (what masks_to_boxes gives, + 1 at the far side).
        if k:
            expected = torchvision.ops.masks_to_boxes(masks) + torch.tensor([0, 0, 1, 1])
            assert torch.equal(boxes.as_subclass(torch.Tensor), expected)
        # The tutorials' operations work on the semantic map (they raise on uint16).
        assert set(torch.unique(target["semantic"]).tolist()) <= {0, 1, 2, 3, 4}


def test_the_area_limit_is_an_option(bean):
    few = sum(len(t["labels"]) for _, t in PlantViews(bean))
    many = sum(len(t["labels"]) for _, t in PlantViews(bean, min_area=1))
    assert many > few


def test_bad_roots_are_clear_errors(bean, tmp_path):
    with pytest.raises(InputError, match="neither a plant folder nor a dataset folder"):
        PlantViews(tmp_path)
    with pytest.raises(InputError, match="a split needs a dataset folder"):
        PlantViews(bean, split="train")


@pytest.mark.slow
def test_mask_rcnn_takes_a_training_step_from_the_dataset(bean):
    from torchvision.models.detection import MaskRCNN
    from torchvision.models.detection.backbone_utils import resnet_fpn_backbone

    torch.manual_seed(0)
    data = PlantViews(bean)
    loader = torch.utils.data.DataLoader(data, batch_size=2, collate_fn=collate)
    backbone = resnet_fpn_backbone(backbone_name="resnet18", weights=None, trainable_layers=5)
    model = MaskRCNN(backbone, num_classes=data.num_classes, min_size=96, max_size=96)
    optimizer = torch.optim.SGD(model.parameters(), lr=0.001, momentum=0.9)
    model.train()
    images, targets = next(iter(loader))
    assert sum(len(t["labels"]) for t in targets) > 0
    losses = model(list(images), list(targets))
    assert {"loss_classifier", "loss_box_reg", "loss_mask"} <= set(losses)
    loss = sum(losses.values())
    assert torch.isfinite(loss)
    before = [p.detach().clone() for p in model.roi_heads.mask_predictor.parameters()]
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    after = list(model.roi_heads.mask_predictor.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(after, before, strict=True))
    assert np.isfinite(float(loss.detach()))
