"""Ground-truth files beside the renders, laid out as a nerfstudio/NeRF dataset.

``labels/view_XXX.png``: 8-bit class ids, 0 = background (and Gaussians of class -1).
Class ids 1..255 are written as they are; a model with other ids (0, negative, > 255) gets
pixel values 1..K in ascending class order, and ``transforms.json`` lists the mapping in
``semantic_classes`` either way. ``labels/preview/view_XXX.png``: the same in colour with a
legend. ``instances/view_XXX.png``: 16-bit, 0 = background or no instance (-1); instance
ids 0..65534 are written as id + 1, a model with other ids gets 1..K in ascending order,
and ``instance_ids`` in ``transforms.json`` lists the mapping either way.
``depth/view_XXX.png``: 16-bit z-depth (along the optical axis, not along the ray), 0 where
there is no plant, in units of ``depth_unit_scale_factor`` input units: 0.001 (millimetres
of the input's units; metres for L-System plants) unless the farthest plant point seen
from any view would not fit 16 bits; then the smallest of 0.01, 0.1, 1, ... that fits, so
depth never saturates. ``transforms.json``: pinhole intrinsics and OpenGL camera-to-world
poses in the frame of ``plant.ply``, with the image, mask (the class map: non-zero is
plant), depth and instance paths of every frame.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from plantdreamer.atomic import atomic_write
from plantdreamer.cameras import Camera
from plantdreamer.labels import MAX_CLASSES, MAX_INSTANCES, check_mask_limits
from plantdreamer.pipeline.truth.ground_truth import GroundTruth, LabelSet
from plantdreamer.pointcloud import NormalizeTransform

DEPTH_UNIT_SCALE = 0.001  # depth PNG value * this = depth in input units, unless too far
MAX_DEPTH_VALUE = 65535  # 16-bit PNG

# Colours of the preview (tab10-like, then repeating); background is black.
_PALETTE = np.array(
    [
        [31, 119, 180], [44, 160, 44], [140, 86, 75], [214, 39, 40], [148, 103, 189],
        [255, 127, 14], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207],
    ],
    dtype=np.uint8,
)  # fmt: skip


class GroundTruthWriter:
    """Writes the ground truth of each view of a run and, at the end, ``transforms.json``."""

    def __init__(
        self,
        out_dir: Path,
        label_set: LabelSet | None,
        transform: NormalizeTransform,
        class_names: dict[int, str] | None = None,
    ) -> None:
        self.out_dir, self.label_set, self.transform = out_dir, label_set, transform
        self.class_names = class_names or {}
        self.frames: list[dict[str, object]] = []
        self.cameras: list[dict[str, object]] = []  # each frame's intrinsics and size
        self.depth_unit_scale = DEPTH_UNIT_SCALE
        self.pixel_values = self.instance_values = None
        if label_set is not None:
            self.pixel_values = class_pixel_values(label_set.classes)
            self.instance_values = instance_pixel_values(label_set.instances)

    def choose_depth_unit(self, means: np.ndarray, cameras: list[Camera]) -> None:
        """The depth unit (before the first ``add``): millimetres of the input's units,
        else the smallest power of ten that holds the farthest point any camera can see
        (a bound: the distance to the far side of the points' bounding sphere)."""
        if len(means) == 0 or not cameras:
            return
        p = np.asarray(means, dtype=np.float64)
        p = p[np.isfinite(p).all(axis=1)]
        if len(p) == 0:
            return
        lo, hi = p.min(axis=0), p.max(axis=0)
        centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
        far = max(float(np.linalg.norm(c.position - centre)) for c in cameras) + radius
        far_input = far / self.transform.scale
        scale = DEPTH_UNIT_SCALE
        while far_input / scale > MAX_DEPTH_VALUE and scale < 1e30:
            scale *= 10
        self.depth_unit_scale = float(f"{scale:.0e}")  # 0.01, not 0.010000000000000002

    def add(
        self,
        name: str,
        image_path: str,
        camera: Camera,
        gt: GroundTruth,
        record: dict[str, object] | None = None,
    ) -> None:
        """Writes one view's maps; ``image_path`` is the render, relative to ``out_dir``;
        ``record``: more keys of its frame (what its rig, background and jitter drew)."""
        frame: dict[str, object] = {
            "file_path": image_path,
            "transform_matrix": self._c2w(camera).tolist(),
            **(record or {}),
        }
        depth = gt.depth.astype(np.float64) / self.transform.scale / self.depth_unit_scale
        _write_png(self.out_dir / "depth" / f"{name}.png", _to_uint16(depth))
        frame["depth_file_path"] = f"depth/{name}.png"
        if self.label_set is not None:
            assert self.pixel_values is not None
            table = np.r_[self.pixel_values, 0].astype(np.uint8)  # index -1: background
            semantic = table[gt.label]
            _write_png(self.out_dir / "labels" / f"{name}.png", semantic)
            _write_png(self.out_dir / "labels" / "preview" / f"{name}.png", self._preview(semantic))
            assert self.instance_values is not None
            inst_ids = np.r_[self.instance_values, 0].astype(np.uint16)  # index -1: none
            _write_png(self.out_dir / "instances" / f"{name}.png", inst_ids[gt.instance])
            frame["mask_path"] = f"labels/{name}.png"
            frame["semantic_path"] = f"labels/{name}.png"
            frame["instance_path"] = f"instances/{name}.png"
        self.frames.append(frame)
        self.cameras.append(_intrinsics(camera))

    def finish(self, camera: Camera) -> None:
        """Writes transforms.json (``camera``: any view, for the shared intrinsics; a frame
        whose camera differs from it gets its own, which win over the shared ones)."""
        shared = _intrinsics(camera)
        meta: dict[str, object] = {
            "camera_model": "OPENCV",
            **shared,
            "depth_unit_scale_factor": self.depth_unit_scale,
        }
        for frame, own in zip(self.frames, self.cameras, strict=True):
            if own != shared:
                frame.update(own)
        if self.label_set is not None:
            assert self.pixel_values is not None
            meta["semantic_classes"] = [
                {"value": int(v), "class": int(c), "name": self._name(int(c))}
                for v, c in zip(self.pixel_values, self.label_set.classes, strict=True)
            ]
            meta["instance_count"] = int(self.label_set.instances.size)
            assert self.instance_values is not None
            meta["instance_ids"] = [
                {"value": int(v), "instance": int(i)}
                for v, i in zip(self.instance_values, self.label_set.instances, strict=True)
            ]
        meta["frames"] = self.frames
        text = json.dumps(meta, indent=2)
        atomic_write(self.out_dir / "transforms.json", lambda tmp: tmp.write_text(text + "\n"))

    def _c2w(self, camera: Camera) -> np.ndarray:
        """OpenGL camera-to-world in the input frame (the normalisation is a uniform scale
        and a shift, so only the camera centre moves)."""
        c2w = camera.to_opengl_c2w().copy()
        c2w[:3, 3] = self.transform.invert(c2w[:3, 3][None, :].astype(np.float64))[0]
        return c2w

    def _name(self, cls: int) -> str:
        return self.class_names.get(cls, f"class {cls}")

    def _preview(self, semantic: np.ndarray) -> np.ndarray:
        from PIL import Image, ImageDraw

        colours = np.zeros((256, 3), dtype=np.uint8)
        assert self.label_set is not None and self.pixel_values is not None
        for i, v in enumerate(self.pixel_values):
            colours[v] = _PALETTE[i % len(_PALETTE)]
        image = Image.fromarray(colours[semantic])
        draw = ImageDraw.Draw(image)
        for i, (v, c) in enumerate(zip(self.pixel_values, self.label_set.classes, strict=True)):
            y = 4 + 14 * i
            draw.rectangle([4, y, 14, y + 10], fill=tuple(int(x) for x in colours[v]))
            draw.text((18, y - 1), f"{int(v)}: {self._name(int(c))}", fill=(255, 255, 255))
        return np.asarray(image)


def _intrinsics(camera: Camera) -> dict[str, object]:
    k = camera.K
    return {
        "fl_x": float(k[0, 0]),
        "fl_y": float(k[1, 1]),
        "cx": float(k[0, 2]),
        "cy": float(k[1, 2]),
        "w": camera.width,
        "h": camera.height,
    }


def class_pixel_values(classes: np.ndarray) -> np.ndarray:
    """The 8-bit value of each class: the id itself when all ids are in 1..255, else 1..K."""
    classes = np.asarray(classes)
    check_mask_limits(np.stack([classes, np.full_like(classes, -1)], axis=1))
    if classes.size == 0 or (classes.min() >= 1 and classes.max() <= MAX_CLASSES):
        return classes.astype(np.uint8)
    return np.arange(1, classes.size + 1, dtype=np.uint8)


def instance_pixel_values(instances: np.ndarray) -> np.ndarray:
    """The 16-bit value of each instance: id + 1 when all ids are in 0..65534, else 1..K."""
    instances = np.asarray(instances)
    check_mask_limits(np.stack([np.full_like(instances, -1), instances], axis=1))
    if instances.size == 0 or (instances.min() >= 0 and instances.max() < MAX_INSTANCES):
        return (instances + 1).astype(np.uint16)
    return np.arange(1, instances.size + 1, dtype=np.uint16)


def _to_uint16(values: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(values), 0, 65535).astype(np.uint16)


def _write_png(path: Path, image: np.ndarray) -> None:
    import imageio.v3 as iio

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: iio.imwrite(tmp, image, extension=".png"))


def ground_truth_writer(
    out_dir: Path,
    model,
    transform: NormalizeTransform,
    labels: bool = True,
    class_names: dict[int, str] | None = None,
) -> GroundTruthWriter:
    """A writer for ``model`` (a ``GaussianModel`` in the scene frame); with ``labels=False``
    or an unlabelled model it writes depth and transforms.json only."""
    label_set = None
    if labels and model.labels is not None:
        label_set = LabelSet.of(model.labels.numpy())
    return GroundTruthWriter(out_dir, label_set, transform, class_names)


def render_views(
    model,
    writer: GroundTruthWriter,
    cameras: list[Camera],
    render,
    keep,
    records: list[dict[str, object]] | None = None,
    observe=None,
) -> None:
    """Renders each view (``render(camera) -> (image, meta)``), hands the image to
    ``keep(index, image)`` (which writes it: ``outputs.StreamedViews.add``) and writes its
    ground truth, whose instance channels reuse the render's footprints (``records``: each
    view's more keys of transforms.json): one view is held at a time.
    ``observe(name, camera, instances, meta)``, if given, sees each view: its instance ids
    per pixel (-1: none; None without labels) and its render's ``meta``."""
    from plantdreamer.pipeline.truth.ground_truth import GroundTruthRenderer

    ground_truth = GroundTruthRenderer(model, writer.label_set)
    writer.choose_depth_unit(model.params["means"].detach().numpy(), cameras)
    for i, camera in enumerate(cameras):
        image, meta = render(camera)
        name = f"view_{i:03d}"
        keep(i, image)
        gt = ground_truth(camera, meta)
        writer.add(name, f"renders/{name}.png", camera, gt, records[i] if records else None)
        if observe is not None:
            ls = writer.label_set
            ids = None if ls is None else np.r_[ls.instances, -1][gt.instance]
            observe(name, camera, ids, meta)
    if cameras:
        writer.finish(cameras[0])
