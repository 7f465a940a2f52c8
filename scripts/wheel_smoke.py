"""Runs an installed plantdreamer the way a user would; `scripts/check_wheel.sh` runs it in a
fresh venv holding only the wheel (no Rust toolchain on PATH).

Checks: the package and its native module come from the venv (the stable-ABI build), the
wheel's metadata carries the Apache-2.0 licence text and the project's URLs, `plantdreamer
info`, a small `plantdreamer render`, and a rasterization with gradients.
"""

from __future__ import annotations

import importlib.metadata
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path


def check(condition: bool, message: str) -> None:
    if not condition:
        raise SystemExit(f"wheel check failed: {message}")


def main() -> None:
    found = [tool for tool in ("cargo", "rustc") if shutil.which(tool)]
    check(not found, f"{', '.join(found)} on PATH; the check needs a PATH without Rust")

    import numpy as np
    import torch

    import plantdreamer
    from plantdreamer import _core, rasterization
    from plantdreamer.cameras import orbit, stack
    from plantdreamer.gaussians import Gaussians
    from plantdreamer.io import write_splat_ply

    site = Path(sysconfig.get_paths()["platlib"]).resolve()
    package = Path(plantdreamer.__file__).resolve().parent
    check(package.parent == site, f"plantdreamer imported from {package}, not from {site}")
    check(Path(_core.__file__).name == "_core.abi3.so", f"native module is {_core.__file__}")

    meta = importlib.metadata.distribution("plantdreamer")
    check(meta.metadata["License-Expression"] == "Apache-2.0", "no licence expression")
    licence = [f for f in meta.files or [] if f.name == "LICENSE"]
    check(len(licence) == 1, f"the wheel ships {len(licence)} LICENSE files, not 1")
    text = licence[0].read_text(encoding="utf-8")
    check("Apache License" in text and "Version 2.0" in text, "LICENSE is not Apache-2.0")
    urls = meta.metadata.get_all("Project-URL") or []
    # The addresses themselves are checked against the reviewed ones (tests/test_urls.py).
    check(any(u.startswith("Paper, ") for u in urls), f"no Paper URL: {urls}")

    cli = [str(Path(sys.executable).with_name("plantdreamer"))]
    info = subprocess.run([*cli, "info"], capture_output=True, text=True, check=True).stdout
    print(info, end="")
    version_line = info.splitlines()[0].split()
    check(version_line == ["plantdreamer", plantdreamer.__version__], "info has no version line")

    rng = np.random.default_rng(0)
    n = 400
    g = Gaussians(
        means=rng.normal(0.0, 0.3, (n, 3)).astype(np.float32),
        quats=np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
        log_scales=np.full((n, 3), np.log(0.05), np.float32),
        opacity_logits=np.full(n, 2.0, np.float32),
        sh=rng.normal(0.0, 1.0, (n, 1, 3)).astype(np.float32),
    )
    with tempfile.TemporaryDirectory() as tmp:
        ply = Path(tmp) / "g.ply"
        write_splat_ply(ply, g)
        out = Path(tmp) / "views"
        args = ["render", str(ply), "--out", str(out), "--eval-views", "2", "--resolution", "48"]
        subprocess.run([*cli, *args, "--turntable", "none"], check=True)
        check(len(list(out.glob("view_*.png"))) == 2, "render wrote no views")

    viewmats, ks = map(torch.from_numpy, stack([orbit(4.0, 15, 30, 55, 64, 64)]))
    means = torch.from_numpy(g.means * 4).requires_grad_(True)
    img, alpha, _ = rasterization(
        means,
        torch.from_numpy(g.quats),
        torch.from_numpy(np.exp(g.log_scales)),
        torch.sigmoid(torch.from_numpy(g.opacity_logits)),
        torch.from_numpy(g.sh),
        viewmats,
        ks,
        64,
        64,
        sh_degree=0,
    )
    img.mean().backward()
    grad = means.grad
    check(grad is not None and bool(torch.isfinite(grad).all()), "gradients are not finite")
    check(float(alpha.detach().max()) > 0.5 and float(grad.abs().sum()) > 0, "nothing drawn")
    print(f"rasterized {n} Gaussians with gradients: |d mean / d means| = {grad.abs().sum():.3g}")
    print("wheel check passed")


if __name__ == "__main__":
    main()
