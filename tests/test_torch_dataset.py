"""``plantdreamer.data.PlantViews``: torchvision-ready items, and one Mask R-CNN training step."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
import torch

from plantdreamer.data import DETECTION_KEYS, TARGET_KEYS, PlantViews, object_keys
from plantdreamer.errors import InputError

torchvision = pytest.importorskip("torchvision")
from plantdreamer.data.pixel_map import PixelMap  # noqa: E402 (needs torchvision)

RECIPES = Path(__file__).parents[1] / "docs" / "datasets.md"


def test_items_have_the_dtypes_detection_models_take(bean):
    from torchvision import tv_tensors

    data = PlantViews(bean)
    assert len(data) == 3 and data.num_classes == 5
    assert data.classes == {1: "leaf", 2: "stem", 3: "pot", 4: "soil"}
    seen = set()
    for i in range(len(data)):
        image, target = data[i]
        seen |= set(target["labels"].tolist())
        assert target["image_id"] == i + 1  # coco.json's image ids
        assert isinstance(target["ignore"], PixelMap)
        assert not (target["ignore"].bool() & target["masks"].bool().any(0)).any()
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
    assert seen == {1, 2, 3, 4}  # every class it declares


def test_v2_transforms_keep_every_per_object_key_with_its_box(bean):
    from torchvision.transforms import v2

    plain = PlantViews(bean)
    crop = v2.Compose([v2.CenterCrop(48), v2.SanitizeBoundingBoxes(labels_getter=object_keys)])
    cropped = PlantViews(bean, transforms=crop)
    dropped = 0
    for i in range(len(plain)):
        _, before = plain[i]
        image, after = cropped[i]
        k = len(after["boxes"])
        assert image.shape[-2:] == (48, 48) and after["masks"].shape == (k, 48, 48)
        assert all(len(after[key]) == k for key in ("labels", "area", "iscrowd", "instance_ids"))
        assert torch.equal(after["area"], after["masks"].flatten(1).sum(1).float())
        dropped += len(before["boxes"]) - k
        # Each kept object is the same object: its mask is its old mask, cropped.
        old = {
            (int(i), int(c), int(b[0]), int(b[1])): m
            for i, c, b, m in zip(
                before["instance_ids"],
                before["labels"],
                before["boxes"],
                before["masks"],
                strict=True,
            )
        }
        top, left = (96 - 48) // 2, (96 - 48) // 2
        for j in range(k):
            matches = [
                m
                for (iid, c, _, _), m in old.items()
                if iid == int(after["instance_ids"][j])
                and c == int(after["labels"][j])
                and torch.equal(m[top : top + 48, left : left + 48], after["masks"][j])
            ]
            assert matches, j
    assert dropped > 0  # the crop removed objects, and the keys followed
    resized = PlantViews(bean, transforms=v2.Resize(192))
    _, target = resized[0]
    assert torch.equal(target["area"], target["masks"].flatten(1).sum(1).float())
    # torchvision's default labels_getter filters "labels" only: refused, naming the fix.
    default = PlantViews(
        bean, transforms=v2.Compose([v2.CenterCrop(48), v2.SanitizeBoundingBoxes()])
    )
    with pytest.raises(InputError, match=r"labels_getter=plantdreamer\.data\.object_keys"):
        for i in range(len(default)):
            default[i]


def detection_reference_train(hflip_prob=0.5, mean=(123.0, 117.0, 104.0)):
    """torchvision's detection references' training transforms (references/detection/
    presets.py, ``DetectionPresetTrain(data_augmentation="ssd", backend="tv_tensor",
    use_v2=True)``) as they are, but for the fill: the images here are float in [0, 1]
    already, so the mean is divided by 255. Its ``RandomIoUCrop`` drops boxes, and the
    default ``SanitizeBoundingBoxes()`` at its end filters boxes, masks and ``labels``."""
    from collections import defaultdict

    from torchvision import tv_tensors
    from torchvision.transforms import v2 as T

    fill = defaultdict(lambda: tuple(m / 255 for m in mean), {tv_tensors.Mask: 0})
    return T.Compose(
        [
            T.ToImage(),
            T.RandomPhotometricDistort(),
            T.RandomZoomOut(fill=fill),
            T.RandomIoUCrop(),
            T.RandomHorizontalFlip(p=hflip_prob),
            T.ToDtype(torch.float, scale=True),
            T.ConvertBoundingBoxFormat(tv_tensors.BoundingBoxFormat.XYXY),
            T.SanitizeBoundingBoxes(),
            T.ToPureTensor(),
        ]
    )


def test_torchvisions_detection_reference_transforms_run_on_the_standard_keys(bean):
    """The keys the references ask for (``target_keys``, as ``wrap_dataset_for_transforms_v2``
    takes them) and their transforms with the default ``SanitizeBoundingBoxes()``: every item
    comes through, each kept mask with its box and label; with every key the same transforms
    are refused, naming both fixes."""
    objects = [len(t["boxes"]) for _, t in PlantViews(bean)]
    data = PlantViews(bean, transforms=detection_reference_train(), target_keys=DETECTION_KEYS)
    torch.manual_seed(0)
    dropped = 0
    for _ in range(2):  # RandomIoUCrop drops boxes in most items
        for i in range(len(data)):
            image, target = data[i]
            assert list(target) == ["boxes", "labels", "masks", "image_id"]
            k = len(target["boxes"])
            assert target["labels"].shape == (k,) and target["masks"].shape == (k, *image.shape[1:])
            assert target["image_id"] == i + 1
            h, w = image.shape[1:]
            boxes = target["boxes"]
            assert ((boxes[:, :2] >= 0) & (boxes[:, 2:] <= torch.tensor([w, h]))).all()
            seen = target["masks"].flatten(1).bool().any(1)
            if seen.any():  # each mask's pixels lie in its box
                tight = torchvision.ops.masks_to_boxes(target["masks"][seen])
                inner = boxes[seen]
                assert (tight[:, :2] >= inner[:, :2] - 1e-4).all()
                assert (tight[:, 2:] + 1 <= inner[:, 2:] + 1e-4).all()
            dropped += objects[i] - k
    assert dropped > 0  # the crops dropped objects, and the default sanitiser followed
    every_key = PlantViews(bean, transforms=detection_reference_train())
    torch.manual_seed(0)
    with pytest.raises(InputError, match=r"target_keys=plantdreamer\.data\.DETECTION_KEYS"):
        for _ in range(2):
            for i in range(len(every_key)):
                every_key[i]


def test_target_keys_choose_the_keys_as_torchvision_takes_them(bean):
    from torchvision.transforms import v2

    _, target = PlantViews(bean, target_keys="all")[0]
    assert tuple(target) == TARGET_KEYS
    assert tuple(PlantViews(bean)[0][1]) == TARGET_KEYS  # None: every key
    chosen = PlantViews(bean, target_keys={"image_id", "semantic"}, transforms=v2.CenterCrop(48))
    _, target = chosen[0]
    assert list(target) == ["semantic", "image_id"] and target["semantic"].shape == (48, 48)
    assert isinstance(target["semantic"], PixelMap)
    with pytest.raises(InputError, match=r"target_keys has no 'mask', 'scores': the keys are"):
        PlantViews(bean, target_keys=["boxes", "mask", "scores"])
    with pytest.raises(InputError, match=r"target_keys=\['boxes'\]"):
        PlantViews(bean, target_keys="boxes")
    with pytest.raises(InputError, match="need boxes"):
        PlantViews(bean, target_keys=["labels", "masks"])
    # The block of docs/datasets.md, on this plant.
    code = readme_block("target_keys=DETECTION_KEYS")
    assert code.count('PlantViews("ds/", split="train", ') == 1
    scope: dict = {}
    exec(code.replace('PlantViews("ds/", split="train", ', f"PlantViews({str(bean)!r}, "), scope)
    torch.manual_seed(0)
    for _, target in scope["data"]:
        assert list(target) == ["boxes", "labels", "masks", "image_id"]
        assert len(target["labels"]) == len(target["boxes"]) == len(target["masks"])


def test_the_targets_are_those_of_the_label_files_options(bean, tmp_path):
    import json
    import shutil

    from plantdreamer.exports.dataset import LabelOptions, write_dataset_exports

    ds = tmp_path / "ds"
    shutil.copytree(bean, ds / "plants" / "a")
    options = LabelOptions((1.0, 0.0, 0.0), 0, 30, True, ("pot", "soil"))
    write_dataset_exports(ds, options)
    coco = json.loads((ds / "coco" / "train.json").read_text())
    data = PlantViews(ds, split="train")
    assert data.min_area == 30
    assert sorted(data.classes) == sorted(c["id"] for c in coco["categories"]) == [1, 2]
    assert data.num_classes == 3
    for _, target in data:
        objects = [
            a["category_id"]
            for a in coco["annotations"]
            if a["image_id"] == target["image_id"] and not a["iscrowd"]
        ]
        assert sorted(target["labels"].tolist()) == sorted(objects)
    # Options other than the recorded ones are refused; the recorded ones may be repeated.
    assert len(PlantViews(ds, split="train", min_area=30, stuff=("pot", "soil"))) == len(data)
    with pytest.raises(InputError, match=r"coco/train\.json was made with --min-instance-area 30"):
        PlantViews(ds, split="train", min_area=16)
    with pytest.raises(InputError, match=re.escape("stuff=()")):
        PlantViews(ds, stuff=())
    # A plant folder reads its coco.json's.
    assert PlantViews(ds / "plants" / "a").num_classes == 3


def test_a_damaged_plant_is_refused_naming_its_file(bean, tmp_path):
    import shutil

    ds = tmp_path / "ds"
    for plant in "ab":
        shutil.copytree(bean, ds / "plants" / plant)
    damaged = ds / "plants" / "b" / "transforms.json"
    damaged.write_text(damaged.read_text()[:100])
    with pytest.raises(InputError, match=re.escape(f"{damaged} is not valid JSON")):
        PlantViews(ds)


def test_per_pixel_maps_keep_their_rows_when_objects_as_many_as_rows(bean):
    """SanitizeBoundingBoxes filters every Mask by its first dimension: an [H, W] map of a
    view with H objects lost the rows of the dropped boxes."""
    from torchvision.transforms import v2

    k = max(len(t["boxes"]) for _, t in PlantViews(bean))
    squash = v2.Compose(
        [v2.Resize((k, 96)), v2.SanitizeBoundingBoxes(min_size=2, labels_getter=object_keys)]
    )
    dropped = 0
    for before, (_, after) in zip(
        PlantViews(bean), PlantViews(bean, transforms=squash), strict=True
    ):
        dropped += len(before[1]["boxes"]) - len(after["boxes"])
        assert after["semantic"].shape == after["ignore"].shape == (k, 96)
        assert isinstance(after["semantic"], PixelMap)
    assert dropped  # the case that lost rows
    # A DataLoader's workers pickle the targets.
    import pickle

    _, target = PlantViews(bean)[0]
    assert torch.equal(pickle.loads(pickle.dumps(target["semantic"])), target["semantic"])


def test_bad_roots_are_clear_errors(bean, tmp_path):
    with pytest.raises(InputError, match="neither a plant folder nor a dataset folder"):
        PlantViews(tmp_path)
    with pytest.raises(InputError, match="a split needs a dataset folder"):
        PlantViews(bean, split="train")


def readme_block(containing):
    """The python code block of docs/datasets.md's recipes that contains ``containing``."""
    blocks = re.findall(r"```python\n(.*?)```", RECIPES.read_text(), flags=re.S)
    (block,) = [b for b in blocks if containing in b]
    return block


@pytest.fixture(scope="module")
def two_views(tmp_path_factory):
    """A plant of two views: one batch of the recipe's loader, the same every epoch."""
    from labelled_plant import make_plant

    return make_plant(tmp_path_factory.mktemp("two") / "plant", eval_views=2, resolution=64)


@pytest.mark.slow  # 6 Mask R-CNN iterations on the CPU
def test_the_readme_mask_rcnn_recipe_trains_with_a_falling_loss(two_views, monkeypatch):
    """The recipe's block (docs/datasets.md) as it is, but for the folder, the number of epochs and a ResNet-18
    backbone in place of ResNet-50 (same constructor arguments), to stay cheap on a CPU."""
    from torchvision.models.detection import MaskRCNN
    from torchvision.models.detection.backbone_utils import resnet_fpn_backbone

    code = readme_block("maskrcnn_resnet50_fpn(")
    assert code.count('PlantViews("ds/", split="train")') == 1 and code.count("epochs = 20") == 1
    code = code.replace('PlantViews("ds/", split="train")', f"PlantViews({str(two_views)!r})")
    code = code.replace("epochs = 20", "epochs = 6")

    def resnet18_mask_rcnn(weights, weights_backbone, num_classes, **settings):
        assert weights is None and weights_backbone is None
        backbone = resnet_fpn_backbone(backbone_name="resnet18", weights=None, trainable_layers=5)
        return MaskRCNN(backbone, num_classes=num_classes, **settings)

    monkeypatch.setattr(torchvision.models.detection, "maskrcnn_resnet50_fpn", resnet18_mask_rcnn)
    printed = []
    torch.manual_seed(0)
    exec(code, {"print": printed.append})
    losses = [float(line.rsplit(" ", 1)[1]) for line in printed]
    assert len(losses) == 6 and all(math.isfinite(v) for v in losses), losses
    assert losses[-1] < 0.8 * losses[0], losses
