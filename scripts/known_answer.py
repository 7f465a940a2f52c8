"""The known answer for SDS: does the real ``generate`` recover a plant's true colours?

    python scripts/known_answer.py --species bean --seed 0 --steps 100 --json ka.json
    python scripts/known_answer.py --models tests/data/known_answer/bean_s0_r64 --device cuda

builds (or reuses, from ~/.cache/plantdreamer/known_answer) tiny models trained on the
plant's true views, runs ``generate`` from noise colours with them and with the untrained
models, and scores both with ``plantdreamer eval``'s masked PSNR on held-out true views.
The JSON also says whether the run's logged timesteps followed the schedule
(``timesteps_follow_schedule``: every draw inside its bounds, uniform within them, independent) and how well the guidance's own noising and noise
prediction recover true latents at the drawn timesteps (``x0_error``, ``x0_error_ok``;
``plantdreamer.known_answer.denoiser``).
``--models DIR`` uses a model folder as it is (the test data); ``--build DIR`` only builds
the models into DIR; ``--verify DIR`` rebuilds DIR's models from its manifest and checks
that every file is bit for bit the same; ``--gate DIR`` prints the cheap CFG-direction gate
of DIR's models (``plantdreamer.known_answer.gate``; ``--gate-colour 0`` or ``1`` from black or
white instead of the wrong colours the models were trained on). See docs/known_answer.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

# spec.py imports nothing heavy: --help stays fast.
from plantdreamer.known_answer.spec import CHECK_STEPS


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--species", default="bean")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--steps", type=int, default=CHECK_STEPS, help="Steps of the scored runs.")
    p.add_argument("--curve", default="", help="More step counts to score, e.g. 25,50.")
    p.add_argument("--guidance-scale", type=float, default=None)
    p.add_argument(
        "--group",
        type=int,
        default=1,
        help="Train the plant first in a group of this many (generate --seeds) and score it.",
    )
    p.add_argument(
        "--device",
        default="cpu",
        help="Run the guidance here: cpu, or cuda (cuda:N) to judge CUDA's precision, batching "
        "and overlap on CUDA; the rasterizer stays on the CPU.",
    )
    p.add_argument(
        "--vae-dtype",
        choices=("float32", "bfloat16", "float16"),
        help="The VAE's precision in the runs (generate's --vae-dtype; default: generate's).",
    )
    p.add_argument(
        "--render",
        type=int,
        help="The training render's size (generate's --resolution; default: the SDS size, "
        "--resolution), e.g. 96 to judge rendering at 1.5x the SDS size against 1x.",
    )
    p.add_argument(
        "--depth-size",
        choices=("sds", "render"),
        help="Where the depth conditioning is made (generate's --depth-size; default: "
        "generate's); differs only with --render.",
    )
    p.add_argument("--json", type=Path, help="Write the figures here.")
    p.add_argument("--models", type=Path, help="A known-answer model folder to use as it is.")
    p.add_argument("--cache", type=Path, help="Model cache (default ~/.cache/plantdreamer/...).")
    p.add_argument("--work-dir", type=Path, help="Keep the runs' outputs here.")
    p.add_argument("--build", type=Path, help="Only build the models into this folder.")
    p.add_argument("--verify", type=Path, help="Rebuild this folder's models; compare bits.")
    p.add_argument("--gate", type=Path, help="Print this folder's CFG-direction cosines.")
    p.add_argument(
        "--gate-colour",
        type=float,
        help="Measure the gate from one flat grey level (0 black, 1 white), not noise.",
    )
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    from plantdreamer.errors import PlantDreamerError

    args = parse_args(argv)
    try:
        return run(args)
    except (PlantDreamerError, OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


def run(args: argparse.Namespace) -> int:
    from plantdreamer.known_answer.build import (
        MANIFEST,
        build_models,
        cached_models,
        differing_files,
        untrained_models,
    )
    from plantdreamer.known_answer.check import check_device, known_answer
    from plantdreamer.known_answer.spec import KnownAnswerSpec

    def say(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    check_device(args.device)  # before any model is built

    if args.verify is not None:
        manifest = json.loads((args.verify / MANIFEST).read_text())
        spec = KnownAnswerSpec(**manifest["spec"])
        with tempfile.TemporaryDirectory() as tmp:
            rebuilt = build_models(spec, Path(tmp) / "models", say)
        differ = differing_files(manifest, rebuilt)
        if differ is not None:
            print(f"error: {differ}", file=sys.stderr)
            return 1
        print(f"{len(rebuilt['sha256'])} files rebuilt bit for bit")
        return 0

    if args.gate is not None:
        from plantdreamer.known_answer.gate import gate_on_unseen_views

        spec = KnownAnswerSpec(**json.loads((args.gate / MANIFEST).read_text())["spec"])
        with tempfile.TemporaryDirectory() as tmp:
            gap, gate = gate_on_unseen_views(
                args.gate, spec, Path(tmp), flat_colour=args.gate_colour
            )
        print(json.dumps({"colour_gap": gap, "cfg_direction": [vars(g) for g in gate]}, indent=2))
        return 0

    spec = KnownAnswerSpec(species=args.species, seed=args.seed, resolution=args.resolution)
    if args.build is not None:
        build_models(spec, args.build, say)
        print(f"wrote {args.build}")
        return 0
    if args.models is not None:
        spec = KnownAnswerSpec(**json.loads((args.models / MANIFEST).read_text())["spec"])
    trained = args.models or cached_models(spec, args.cache, say)
    untrained = untrained_models(spec, args.cache)
    curve = [int(s) for s in args.curve.split(",") if s.strip()]
    settings: dict[str, object] = {"group": args.group} if args.group > 1 else {}
    if args.guidance_scale is not None:
        settings["guidance_scale"] = args.guidance_scale
    if args.vae_dtype is not None:
        settings["vae_dtype"] = args.vae_dtype
    if args.render is not None:
        settings["resolution"] = args.render
    if args.depth_size is not None:
        settings["depth_size"] = args.depth_size
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work_dir or Path(tmp)
        figures = known_answer(
            spec, trained, untrained, work, args.steps, curve, device=args.device, **settings
        )
    figures["device"] = args.device
    figures["total_seconds"] = time.perf_counter() - t0
    text = json.dumps(figures, indent=2)
    if args.json is not None:
        from plantdreamer.atomic import write_text

        write_text(args.json, text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
