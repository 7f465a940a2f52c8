"""Dataset loaders: transforms.json, COLMAP text, masks, and camera conventions."""

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from plantdreamer.cameras import orbit
from plantdreamer.errors import InputError
from plantdreamer.eval.colmap import quat_to_rotation
from plantdreamer.eval.datasets import (
    load_colmap_text,
    load_dataset,
    load_transforms_json,
    scan_dataset,
)

W, H = 40, 30


def _save_rgb(path: Path, seed: int = 0, alpha: np.ndarray | None = None) -> np.ndarray:
    path.parent.mkdir(parents=True, exist_ok=True)
    rgb = np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8)
    if alpha is None:
        Image.fromarray(rgb).save(path)
    else:
        Image.fromarray(np.dstack([rgb, alpha]), "RGBA").save(path)
    return rgb


def _gl_pose(position=(0.0, 0.0, 4.0)) -> list[list[float]]:
    """OpenGL camera-to-world: axes aligned with the world, camera looking along -z."""
    c2w = np.eye(4)
    c2w[:3, 3] = position
    return c2w.tolist()


def _write_json(root: Path, meta: dict) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    (root / "transforms.json").write_text(json.dumps(meta))
    return root


def test_camera_angle_x_and_extensionless_paths(tmp_path):
    rgb = _save_rgb(tmp_path / "train" / "r_0.png")
    angle = 2 * math.atan(W / 2 / 50.0)  # fx = 50
    _write_json(
        tmp_path,
        {
            "camera_angle_x": angle,
            "frames": [{"file_path": "./train/r_0", "transform_matrix": _gl_pose()}],
        },
    )
    (frame,) = load_transforms_json(tmp_path)
    assert frame.name == "r_0"
    assert frame.image.dtype == np.float32 and frame.image.shape == (H, W, 3)
    np.testing.assert_array_equal(frame.image, rgb / np.float32(255.0))
    assert frame.mask is None and frame.alpha is None
    k = frame.camera.K
    np.testing.assert_allclose([k[0, 0], k[1, 1], k[0, 2], k[1, 2]], [50, 50, W / 2, H / 2])
    assert (frame.camera.width, frame.camera.height) == (W, H)
    # The JSON file itself is accepted too.
    assert load_transforms_json(tmp_path / "transforms.json")[0].name == "r_0"


def test_fl_xy_cxcy_with_per_frame_override(tmp_path):
    _save_rgb(tmp_path / "images" / "a.jpg")
    _save_rgb(tmp_path / "images" / "b.png")
    _write_json(
        tmp_path,
        {
            "fl_x": 60.0,
            "fl_y": 62.0,
            "cx": 19.0,
            "cy": 14.5,
            "w": W,
            "h": H,
            "frames": [
                {"file_path": "images/a.jpg", "transform_matrix": _gl_pose()},
                {"file_path": "images/b", "transform_matrix": _gl_pose(), "fl_x": 70.0},
            ],
        },
    )
    a, b = load_transforms_json(tmp_path)
    np.testing.assert_allclose(a.camera.K, [[60, 0, 19], [0, 62, 14.5], [0, 0, 1]])
    assert b.camera.K[0, 0] == 70.0 and b.camera.K[1, 1] == 62.0


def test_opengl_pose_projects_where_the_convention_says(tmp_path):
    # Camera at (0, 0, 4) looking down -z (OpenGL), y up in the image.
    _save_rgb(tmp_path / "img.png")
    _write_json(
        tmp_path,
        {
            "fl_x": 50.0,
            "fl_y": 50.0,
            "cx": 20.0,
            "cy": 15.0,
            "frames": [{"file_path": "img.png", "transform_matrix": _gl_pose()}],
        },
    )
    cam = load_transforms_json(tmp_path)[0].camera
    uv, z = cam.project(np.array([[0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(z, [4.0, 4.0, 3.0])
    np.testing.assert_allclose(uv[0], [20 + 50 * 0.5 / 4, 15.0])  # +x: right
    np.testing.assert_allclose(uv[1], [20.0, 15 - 50 * 0.5 / 4])  # +y: up (smaller row)
    np.testing.assert_allclose(uv[2], [20.0, 15.0])
    np.testing.assert_allclose(cam.position, [0, 0, 4])


def test_transforms_round_trip_of_orbit_cameras(tmp_path):
    cams = [orbit(3.5, el, az, 50.0, W, H) for el, az in [(10, 0), (45, 130), (-5, -70)]]
    frames = []
    for i, cam in enumerate(cams):
        _save_rgb(tmp_path / f"v{i}.png", seed=i)
        frames.append({"file_path": f"v{i}.png", "transform_matrix": cam.to_opengl_c2w().tolist()})
    k = cams[0].K
    _write_json(
        tmp_path,
        {"fl_x": k[0, 0], "fl_y": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], "frames": frames},
    )
    loaded = load_dataset(tmp_path)
    pts = np.random.default_rng(0).uniform(-0.5, 0.5, (20, 3))
    for cam, frame in zip(cams, loaded, strict=True):
        np.testing.assert_allclose(frame.camera.viewmat, cam.viewmat, atol=1e-12)
        np.testing.assert_allclose(frame.camera.project(pts)[0], cam.project(pts)[0], atol=1e-9)


def test_masks_from_alpha_and_from_masks_folder(tmp_path):
    alpha = np.zeros((H, W), np.uint8)
    alpha[5:20, 10:30] = 255
    alpha[5, 10] = 1  # any non-zero alpha counts as plant
    _save_rgb(tmp_path / "a.png", alpha=alpha)
    _save_rgb(tmp_path / "b.png", seed=1)
    _save_rgb(tmp_path / "c.png", seed=2, alpha=np.full((H, W), 255, np.uint8))
    mask_b = np.zeros((H, W), np.uint8)
    mask_b[:10] = 7
    (tmp_path / "masks").mkdir()
    Image.fromarray(mask_b).save(tmp_path / "masks" / "b.png")
    pose = _gl_pose()
    _write_json(
        tmp_path,
        {
            "camera_angle_x": 1.0,
            "frames": [{"file_path": f"{n}.png", "transform_matrix": pose} for n in "abc"],
        },
    )
    a, b, c = load_transforms_json(tmp_path)
    np.testing.assert_array_equal(a.mask, alpha != 0)
    np.testing.assert_allclose(a.alpha, alpha / np.float32(255.0))
    np.testing.assert_array_equal(b.mask, mask_b != 0)
    assert b.alpha is None
    # An alpha channel that is opaque everywhere is no mask.
    assert c.mask is None and c.alpha is None
    # RGBA ground truth is composited over the evaluation background.
    gt = a.ground_truth((1.0, 0.0, 0.0))
    np.testing.assert_allclose(gt[0, 0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(gt[10, 15], a.image[10, 15])
    np.testing.assert_array_equal(b.ground_truth((1.0, 0.0, 0.0)), b.image)


def test_nerfstudio_mask_path(tmp_path):
    _save_rgb(tmp_path / "img.png")
    m = np.zeros((H, W), np.uint8)
    m[3:6, 3:6] = 255
    (tmp_path / "seg").mkdir()
    Image.fromarray(m).save(tmp_path / "seg" / "m.png")
    _write_json(
        tmp_path,
        {
            "camera_angle_x": 1.0,
            "frames": [
                {"file_path": "img.png", "mask_path": "seg/m.png", "transform_matrix": _gl_pose()}
            ],
        },
    )
    assert load_transforms_json(tmp_path)[0].mask.sum() == 9


def test_missing_files_and_bad_metadata_are_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        load_dataset(tmp_path / "nope")
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "transforms_test.json").write_text("{}")
    with pytest.raises(InputError, match=r"transforms_test\.json"):
        load_dataset(empty)
    with pytest.raises(FileNotFoundError, match=r"transforms_test\.json"):
        load_transforms_json(empty)
    root = _write_json(
        tmp_path / "d",
        {"camera_angle_x": 1.0, "frames": [{"file_path": "gone", "transform_matrix": _gl_pose()}]},
    )
    with pytest.raises(FileNotFoundError, match="gone"):
        load_transforms_json(root)
    _save_rgb(root / "x.png")
    _write_json(root, {"frames": [{"file_path": "x.png", "transform_matrix": _gl_pose()}]})
    with pytest.raises(InputError, match="intrinsics"):
        load_transforms_json(root)
    _write_json(root, {"camera_angle_x": 1, "frames": [{"file_path": "x.png"}]})
    with pytest.raises(InputError, match="transform_matrix"):
        load_transforms_json(root)
    _write_json(
        root,
        {
            "camera_angle_x": 1,
            "w": W + 1,
            "h": H,
            "frames": [{"file_path": "x.png", "transform_matrix": _gl_pose()}],
        },
    )
    with pytest.raises(InputError, match="image is 40x30"):
        load_transforms_json(root)
    _write_json(
        root,
        {
            "camera_angle_x": 1,
            "frames": [
                {"file_path": "x.png", "mask_path": "no.png", "transform_matrix": _gl_pose()}
            ],
        },
    )
    with pytest.raises(FileNotFoundError, match="mask"):
        load_transforms_json(root)
    (root / "transforms.json").write_text("{not json")
    with pytest.raises(InputError, match="JSON"):
        load_transforms_json(root)
    _write_json(root, {"camera_angle_x": 1, "frames": []})
    with pytest.raises(InputError, match="no frames"):
        load_transforms_json(root)


def test_distortion_and_fisheye_in_transforms(tmp_path):
    _save_rgb(tmp_path / "x.png")
    meta = {
        "fl_x": 50.0,
        "k1": 0.1,
        "frames": [{"file_path": "x.png", "transform_matrix": _gl_pose()}],
    }
    _write_json(tmp_path, meta)
    with pytest.warns(UserWarning, match="distortion"):
        load_transforms_json(tmp_path)
    _write_json(tmp_path, {**meta, "camera_model": "OPENCV_FISHEYE"})
    with pytest.raises(InputError, match=r"fisheye|pinhole"):
        load_transforms_json(tmp_path)


# --- COLMAP ---------------------------------------------------------------------------------


def _colmap(root: Path, cameras: str, images: str) -> Path:
    model = root / "sparse" / "0"
    model.mkdir(parents=True, exist_ok=True)
    (model / "cameras.txt").write_text(cameras)
    (model / "images.txt").write_text(images)
    return root


CAMERAS_TXT = f"""# Camera list with one line of data per camera:
#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]
1 PINHOLE {W} {H} 50 52 20 15
2 SIMPLE_PINHOLE {W} {H} 45 19.5 14.5
"""


def test_colmap_text_parsing_and_convention(tmp_path):
    _save_rgb(tmp_path / "images" / "b.png", seed=1)
    _save_rgb(tmp_path / "images" / "a.png", seed=2)
    # Image "b": identity rotation, t = (0, 0, 4): camera at (0, 0, -4) looking along +z.
    # Image "a": a quaternion for a 90 degree turn about z and a translation.
    s = math.sqrt(0.5)
    images = (
        "# Image list with two lines of data per image:\n"
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
        "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
        "7 1 0 0 0 0 0 4 1 b.png\n"
        "\n"
        f"3 {s} 0 0 {s} 0.5 -0.25 3 2 a.png\n"
        "10.0 12.0 -1 11.5 3.0 4\n"
    )
    frames = load_colmap_text(_colmap(tmp_path, CAMERAS_TXT, images))
    assert [f.name for f in frames] == ["a", "b"]
    a, b = frames
    np.testing.assert_allclose(b.camera.K, [[50, 0, 20], [0, 52, 15], [0, 0, 1]])
    np.testing.assert_allclose(a.camera.K, [[45, 0, 19.5], [0, 45, 14.5], [0, 0, 1]])
    np.testing.assert_allclose(b.camera.position, [0, 0, -4])
    uv, z = b.camera.project(np.array([[0.5, 0.0, 0.0], [0.0, 0.5, 0.0]]))
    np.testing.assert_allclose(z, [4.0, 4.0])
    np.testing.assert_allclose(uv, [[20 + 50 * 0.5 / 4, 15], [20, 15 + 52 * 0.5 / 4]])  # y down
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(a.camera.viewmat[:3, :3], rot, atol=1e-12)
    np.testing.assert_allclose(a.camera.viewmat[:3, 3], [0.5, -0.25, 3])
    assert load_dataset(tmp_path)[1].name == "b"  # auto-detected


def test_colmap_and_opengl_describe_the_same_camera(tmp_path):
    cam = orbit(3.0, 30.0, 60.0, 50.0, W, H)
    # COLMAP: world-to-camera OpenCV as a quaternion + t.
    r = cam.viewmat[:3, :3]
    qw = math.sqrt(max(0.0, 1 + np.trace(r))) / 2
    qx, qy, qz = (
        (r[2, 1] - r[1, 2]) / (4 * qw),
        (r[0, 2] - r[2, 0]) / (4 * qw),
        (r[1, 0] - r[0, 1]) / (4 * qw),
    )
    np.testing.assert_allclose(quat_to_rotation(qw, qx, qy, qz), r, atol=1e-12)
    qw, qx, qy, qz = (float(q) for q in (qw, qx, qy, qz))
    t = [float(x) for x in cam.viewmat[:3, 3]]
    _save_rgb(tmp_path / "colmap" / "images" / "v.png")
    k = cam.K.tolist()
    cams = f"1 PINHOLE {W} {H} {k[0][0]!r} {k[1][1]!r} {k[0][2]!r} {k[1][2]!r}\n"
    imgs = f"1 {qw!r} {qx!r} {qy!r} {qz!r} {t[0]!r} {t[1]!r} {t[2]!r} 1 v.png\n\n"
    from_colmap = load_colmap_text(_colmap(tmp_path / "colmap", cams, imgs))[0].camera
    # nerfstudio: OpenGL camera-to-world.
    _save_rgb(tmp_path / "ns" / "v.png")
    _write_json(
        tmp_path / "ns",
        {
            "fl_x": k[0][0],
            "fl_y": k[1][1],
            "cx": k[0][2],
            "cy": k[1][2],
            "frames": [{"file_path": "v.png", "transform_matrix": cam.to_opengl_c2w().tolist()}],
        },
    )
    from_gl = load_transforms_json(tmp_path / "ns")[0].camera
    np.testing.assert_allclose(from_colmap.viewmat, from_gl.viewmat, atol=1e-12)
    np.testing.assert_allclose(from_colmap.viewmat, cam.viewmat, atol=1e-12)


def test_colmap_radial_models_warn_and_fisheye_is_rejected(tmp_path):
    _save_rgb(tmp_path / "images" / "v.png")
    imgs = "1 1 0 0 0 0 0 4 1 v.png\n\n"
    for line in (
        f"1 SIMPLE_RADIAL {W} {H} 50 20 15 0.01",
        f"1 OPENCV {W} {H} 50 50 20 15 0.1 0 0 0",
    ):
        _colmap(tmp_path, line + "\n", imgs)
        with pytest.warns(UserWarning, match="distortion"):
            (f,) = load_colmap_text(tmp_path)
        assert f.camera.K[0, 0] == 50.0 and f.camera.K[0, 2] == 20.0
    _colmap(tmp_path, f"1 RADIAL {W} {H} 50 20 15 0 0\n", imgs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # zero distortion: no warning
        load_colmap_text(tmp_path)
    _colmap(tmp_path, f"1 OPENCV_FISHEYE {W} {H} 50 50 20 15 0 0 0 0\n", imgs)
    with pytest.raises(InputError, match="OPENCV_FISHEYE"):
        load_colmap_text(tmp_path)


def test_colmap_points_lines_may_be_missing(tmp_path):
    _save_rgb(tmp_path / "images" / "a.png")
    _save_rgb(tmp_path / "images" / "0002.png", seed=1)  # listed without extension
    _save_rgb(tmp_path / "images" / "c.png", seed=2)
    images = (
        "1 1 0 0 0 0 0 4 1 a.png\n"  # no points line at all
        "2 1 0 0 0 0 0 5 1 0002\n"
        "1.0 2.0 7 3.0 4.0 -1\n"  # two points
        "3 1 0 0 0 0 0 6 2 c.png\n"
    )
    frames = load_colmap_text(_colmap(tmp_path, CAMERAS_TXT, images))
    assert [f.name for f in frames] == ["0002", "a", "c"]
    assert [f.camera.viewmat[2, 3] for f in frames] == [5.0, 4.0, 6.0]


def test_colmap_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="COLMAP"):
        load_colmap_text(tmp_path)
    _colmap(tmp_path, CAMERAS_TXT, "1 1 0 0 0 0 0 4 9 v.png\n\n")
    with pytest.raises(InputError, match="camera 9"):
        load_colmap_text(tmp_path)
    _colmap(tmp_path, CAMERAS_TXT, "1 1 0 0 0 0 0 4 1 missing.png\n\n")
    with pytest.raises(FileNotFoundError, match=r"missing\.png"):
        load_colmap_text(tmp_path)
    _colmap(tmp_path, f"1 PINHOLE {W} {H} 50 20\n", "")
    with pytest.raises(InputError, match="4 parameters"):
        load_colmap_text(tmp_path)
    _save_rgb(tmp_path / "images" / "v.png")
    _colmap(tmp_path, f"1 PINHOLE {W + 2} {H} 50 50 20 15\n", "1 1 0 0 0 0 0 4 1 v.png\n\n")
    with pytest.raises(InputError, match="42x30"):
        load_colmap_text(tmp_path)
    _colmap(tmp_path, CAMERAS_TXT, "# nothing\n")
    with pytest.raises(InputError, match="no images"):
        load_colmap_text(tmp_path)


def test_image_modes(tmp_path):
    from plantdreamer.eval.images import read_mask, read_rgba

    gray = np.arange(H * W, dtype=np.uint8).reshape(H, W)
    Image.fromarray(gray, "L").save(tmp_path / "l.png")
    rgb, alpha = read_rgba(tmp_path / "l.png")
    np.testing.assert_array_equal(rgb[..., 1], gray / np.float32(255.0))
    assert alpha is None
    Image.fromarray(np.dstack([gray, 255 - gray]), "LA").save(tmp_path / "la.png")
    rgb, alpha = read_rgba(tmp_path / "la.png")
    np.testing.assert_allclose(alpha, (255 - gray) / 255.0, atol=1e-7)
    deep = (np.arange(H * W, dtype=np.uint16).reshape(H, W) * 50).astype(np.uint16)
    Image.fromarray(deep).save(tmp_path / "i16.png")
    rgb, alpha = read_rgba(tmp_path / "i16.png")
    np.testing.assert_allclose(rgb[..., 0], deep / 65535.0, atol=1e-7)
    pal = Image.fromarray(gray % 4, "L").convert("P")
    pal.save(tmp_path / "p.png")
    assert read_rgba(tmp_path / "p.png")[0].shape == (H, W, 3)
    np.testing.assert_array_equal(read_mask(tmp_path / "l.png"), gray != 0)
    rgb_mask = np.zeros((H, W, 3), np.uint8)
    rgb_mask[2, 3] = [0, 0, 9]  # a colour mask: grayscale non-zero
    Image.fromarray(rgb_mask).save(tmp_path / "m.png")
    assert read_mask(tmp_path / "m.png").sum() == 1
    (tmp_path / "junk.png").write_bytes(b"not an image")
    with pytest.raises(InputError, match="cannot read image"):
        read_rgba(tmp_path / "junk.png")


def test_scan_reads_no_pixels_until_load(tmp_path):
    alpha = np.zeros((H, W), np.uint8)
    alpha[4:9, 4:9] = 200
    _save_rgb(tmp_path / "a.png", alpha=alpha)
    _save_rgb(tmp_path / "b.png", seed=1)
    (tmp_path / "masks").mkdir()
    Image.fromarray(np.full((H, W - 1), 255, np.uint8)).save(tmp_path / "masks" / "b.png")
    pose = _gl_pose()
    _write_json(
        tmp_path,
        {
            "fl_x": 50.0,
            "frames": [{"file_path": f"{n}.png", "transform_matrix": pose} for n in "ab"],
        },
    )
    a_src, b_src = scan_dataset(tmp_path)
    assert a_src.mask_path is None and b_src.mask_path == tmp_path / "masks" / "b.png"
    a = a_src.load()
    np.testing.assert_array_equal(a.mask, alpha != 0)
    assert a.image.shape == (H, W, 3) and a.alpha is not None
    with pytest.raises(InputError, match="mask"):
        b_src.load()  # the mask file is one pixel narrower than its image
    # The image changed size between scan and load: caught, not silently mis-scored.
    Image.fromarray(np.zeros((H + 2, W, 3), np.uint8)).save(tmp_path / "a.png")
    with pytest.raises(InputError, match="camera is 40x30"):
        a_src.load()


def test_images_over_the_pixel_bound_are_clear_errors(tmp_path, monkeypatch):
    from PIL import Image

    from plantdreamer.eval.images import read_mask, read_rgba

    path = tmp_path / "gt.png"
    Image.new("RGB", (64, 64)).save(path)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # Pillow's bomb limit, made tiny
    with pytest.raises(InputError, match=r"cannot read image .*gt\.png.*decompression bomb"):
        read_rgba(path)
    with pytest.raises(InputError, match=r"cannot read mask .*gt\.png.*decompression bomb"):
        read_mask(path)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", None)
    monkeypatch.setattr("plantdreamer.eval.images.MAX_IMAGE_PIXELS", 4000)
    with pytest.raises(InputError, match="64 x 64 pixels is above the limit"):
        read_rgba(path)
