"""Per-step time breakdown of `plantdreamer generate` on this machine.

Two configurations, both from the L-System bean (seed 0, 100k points, 512x512 renders):
- `--guidance none` (no diffusion model). Nothing is optimised, so no step renders; the time is the
  preparation, culling rounds, export and the evaluation renders.
- tiny SDS: the full training step (render, depth conditioning, SDS with random-weight tiny
  diffusion models, backward, Adam) for a few steps. The tiny UNet costs far less than
  SD 2.1's, so its `guidance` row is a floor; the other rows are the real per-step costs.

    python benches/bench_generate.py
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def run(cfg, guidance=None):
    from plantdreamer.pipeline import generate_plants

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        generate_plants([cfg], tmp, guidance=guidance, show_progress=False)
        wall = time.perf_counter() - t0
        summary = json.loads((Path(tmp) / "run.json").read_text())
    return wall, summary


def main() -> int:
    from plantdreamer.guidance.sds import StableDiffusionDepthGuidance
    from plantdreamer.guidance.tiny import tiny_models
    from plantdreamer.pipeline import GenerateConfig

    rows = []
    demo = GenerateConfig.of(species="bean", guidance="none", resolution=512)
    wall, summary = run(demo)
    rows.append(("none (no guidance, 3600 steps)", wall, summary))

    steps = 20
    sds_cfg = GenerateConfig.of(
        species="bean", guidance="sds", resolution=512, steps=steps, eval_views=8
    )
    guidance = StableDiffusionDepthGuidance(species="bean", components=tiny_models(), seed=0)
    wall, summary = run(sds_cfg, guidance)
    rows.append((f"tiny SDS ({steps} steps)", wall, summary))

    from plantdreamer.pipeline.export import STEP_PHASES

    lines = [
        "## Generation pipeline (`benches/bench_generate.py`)\n",
        "Command: `python benches/run_all.py generate`. L-System bean, seed 0, 100k points,",
        "512x512 renders, CPU only (no CUDA GPU on the benchmark machine). Per-step columns are",
        "milliseconds per trained step; `prepare` (L-System + sampling + kNN init), `renders`",
        "(evaluation orbit) and the total are seconds. Measured on a shared, loaded 2-core",
        "machine: treat them as upper bounds.\n",
        "| guidance | "
        + " | ".join(f"{p} (ms/step)" for p in STEP_PHASES)
        + " | densify + cull (s) | prepare (s) | renders (s) | total (s) |",
        "|---|" + "---|" * (len(STEP_PHASES) + 4),
    ]
    for name, wall, s in rows:
        per = s["per_step_s"]
        t = s["timings_s"]
        cells = [f"{1000 * per[p]:.1f}" if p in per else "-" for p in STEP_PHASES]
        lines.append(
            f"| {name} | "
            + " | ".join(cells)
            + f" | {t.get('densify', 0) + t.get('cull', 0):.2f}"
            + f" | {t.get('prepare', 0):.2f} | {t.get('renders', 0):.2f} | {wall:.1f} |"
        )
    lines.append("")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "generate.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
