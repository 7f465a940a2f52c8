"""benches/bench_throughput.py through `scripts/gpu_checks.py throughput`: the steady-state
figures and the report's schema, run with tiny networks on the CPU (the same script a CUDA
host runs at full size)."""

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benches"))

import bench_throughput  # noqa: E402

KEYS = ("step_ms_median", "plants_per_hour", "gpu_busy", "host_core_ms_per_plant_step",
        "host_serial_ms_per_step", "peak_cuda_gib", "device_ms_per_plant_step")  # fmt: skip


def test_the_steady_state_is_the_median_gap_after_warm_up():
    clock = bench_throughput.StepClock(warmup=2)
    # Step ends at 0, 10 (warm-up), then gaps of 1, 3, 2 s; CPU 4 s over the window.
    clock.wall = [0.0, 10.0, 11.0, 14.0, 16.0]
    clock.cpu = [0.0, 20.0, 21.0, 23.0, 24.0]
    clock.serial = [0.0, 5.0, 5.5, 6.0, 6.5]  # the step thread: 0.5 s a step
    s = clock.steady(b=4)
    assert s["steady_steps"] == 3 and s["step_ms_median"] == 2000.0 and s["step_ms_min"] == 1000
    assert s["plants_per_hour"] == 3600 * 4 / (2.0 * 3600)
    assert math.isclose(s["host_core_ms_per_plant_step"], 4000 / (3 * 4))
    assert math.isclose(s["host_serial_ms_per_step"], 500.0)


def test_the_gpu_window_opens_after_warm_up_and_closes_at_the_last_step():
    events = []
    clock = bench_throughput.StepClock(warmup=2, on_window=lambda e: events.append((e, len(clock.wall))),
                                       last=4)  # fmt: skip
    for step in range(5):
        clock(step)
    assert events == [("start", 2), ("stop", 5)]


def test_the_bench_reports_the_steps_own_phases():
    from plantdreamer.pipeline.export import STEP_PHASES

    assert bench_throughput.PHASES == STEP_PHASES


def test_the_variants_leave_out_what_one_plant_cannot_compare():
    args = argparse.Namespace(
        groups=[1, 4], overlap=["off", "on"], vae=["float32"], cuda_wait=["spin", "sleep"],
    )  # fmt: skip
    labels = [v.label for v in bench_throughput.variants(args)]
    assert labels == [
        "1-spin-wait", "1",  # one plant: no halves, so once
        "4-spin-wait", "4", "4-overlap-spin-wait", "4-overlap",
    ]  # fmt: skip
    args.overlap, args.cuda_wait = ["on"], ["sleep"]
    assert [v.label for v in bench_throughput.variants(args)] == ["1", "4-overlap"]
    args.stub_depth = ["on", "off"]
    assert [v.label for v in bench_throughput.variants(args)] == [
        "1", "1-no-depth", "4-overlap", "4-overlap-no-depth",
    ]  # fmt: skip
    args.stub_depth = None
    args.renders, args.baseline = [768, 512], "old"
    assert [v.label for v in bench_throughput.variants(args)] == [
        "1-r768-baseline", "1-r768", "1-r512-baseline", "1-r512",
        "4-overlap-r768-baseline", "4-overlap-r768", "4-overlap-r512-baseline", "4-overlap-r512",
    ]  # fmt: skip


def test_too_few_steps_for_the_warm_up_is_one_clear_error(tmp_path):
    cmd = [sys.executable, "scripts/gpu_checks.py", "throughput", str(tmp_path), "--tiny",
           "--steps", "3", "--warmup", "7"]  # fmt: skip
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0
    assert done.stderr.strip().splitlines()[-1].startswith("error: --steps (3) must exceed")


@pytest.mark.slow
def test_gpu_checks_throughput_tiny_on_the_cpu(tmp_path):
    out = tmp_path / "out"
    cmd = [
        sys.executable, "scripts/gpu_checks.py", "throughput", str(out), "--tiny",
        "--groups", "2", "1", "--overlap", "off", "on", "--steps", "4", "--warmup", "2",
        "--points", "1500", "--render", "48", "--sds", "64", "--work", str(tmp_path / "work"),
        "--trace", str(out / "step.json"),
    ]  # fmt: skip
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    report = json.loads((out / "throughput.json").read_text())
    assert report["device"] == "cpu" and report["warmup"] == 2
    assert set(report["groups"]) == {"1", "2", "2-overlap"}  # no halves for one plant
    for label, row in report["groups"].items():
        assert set(KEYS) <= set(row), label
        assert row["gpu_busy"] is None and row["peak_cuda_gib"] is None
        assert row["device_ms_per_plant_step"] is None
        for key in ("step_ms_median", "plants_per_hour", "host_core_ms_per_plant_step",
                    "host_serial_ms_per_step"):  # fmt: skip
            assert math.isfinite(row[key]) and row[key] > 0, (label, key, row[key])
        # The step's own thread is part of the process, and busy at most the whole step.
        assert row["host_serial_ms_per_step"] <= row["step_ms_median"] * 1.5, label
        assert row["steady_steps"] == 2
        assert set(row["phases_ms"]) == set(bench_throughput.PHASES)
    two = report["groups"]["2"]
    assert math.isclose(two["plants_per_hour"], 2 / (two["step_ms_median"] / 1000))
    assert report["resume"]["stopped_at"] in (2, 3) and all(report["resume"]["identical"].values())
    trace = json.loads((out / "step.json").read_text())
    names = {e.get("name") for e in trace["traceEvents"]}
    assert {"raster.forward", "guidance.launch", "guidance.wait", "raster.backward"} <= names
    assert "optimizer" in names
    assert "| this | 2 | 48 | on | float32 |" in (out / "throughput.md").read_text()
    # The timeline drawn from that trace: the step's phases in one thread's lane, nested
    # ranges (the Adams' zero_grad inside "raster.backward") one level deeper, and each plant's
    # Adam step off the step's thread (the schedule's pool: B = 2 is the traced run).
    sys.path.insert(0, str(ROOT / "scripts"))
    import plot_timeline

    found = plot_timeline.lanes(trace["traceEvents"])
    main = next(
        lane for lane in found.values() if any(n == "raster.forward" for *_, n in lane["ranges"])
    )
    ranges = sorted(main["ranges"])
    depth = dict(zip((n for *_, n in ranges), plot_timeline.depths(ranges), strict=True))
    assert depth["raster.forward"] == 0 and depth["Optimizer.zero_grad#Adam.zero_grad"] == 1
    adams = [lane for lane in found.values()
             if any(n == "Optimizer.step#Adam.step" for *_, n in lane["ranges"])]  # fmt: skip
    assert adams and main not in adams  # (one pool thread may take both tasks)
    assert plot_timeline.main([str(out / "step.json"), str(out / "step.png")]) == 0
    assert (out / "step.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_stub_guidance_gives_every_render_a_fixed_gradient_and_still_wants_depth():
    import torch
    from stub_guidance import StubGuidance

    from plantdreamer.cameras import orbit as orbit_camera

    stub = StubGuidance(resolution=16)
    assert stub.needs_depth and stub.resolution == 16
    cam = orbit_camera(3.0, 20.0, 30.0, 50.0, 8, 8)
    grads = []
    for step, images in enumerate([torch.rand(2, 8, 8, 3), torch.rand(2, 8, 8, 3)]):
        images.requires_grad_(True)
        (stub(images, None, [cam, cam], step).loss * 2).backward()
        grads.append(images.grad)
    assert torch.equal(grads[0], grads[1]) and torch.equal(grads[0][0], grads[0][1])
    assert torch.equal(grads[0][0], StubGuidance(resolution=16)._pattern((8, 8, 3)))


def test_the_bench_measures_the_host_alone_with_the_stub(tmp_path):
    args = argparse.Namespace(
        device="cpu", tiny=True, networks="stub", steps=4, warmup=2, points=1500, render=32,
        sds=16,
    )  # fmt: skip
    row = bench_throughput.one_run(bench_throughput.Variant(2), args, parts=None)
    assert row["steady_steps"] == 2 and row["phases_ms"]["depth"] > 0
    alone = bench_throughput.one_run(
        bench_throughput.Variant(2, stub_depth="off"), args, parts=None
    )
    assert alone["stub_depth"] == "off" and alone["phases_ms"]["depth"] == 0
    assert 0 < row["host_serial_ms_per_step"] and row["host_core_ms_per_plant_step"] > 0
    # Two plants' two window cameras each (16 asked for; none rendered twice).
    assert row["raster_core_ms_per_plant"] > 0 and row["raster_renders"] == 4
    assert row["raster_range"][0] <= 1.0 <= row["raster_range"][1]
    assert (
        row["host_to_raster"]
        == row["host_core_ms_per_plant_step"] / row["raster_core_ms_per_plant"]
    )


@pytest.mark.slow
def test_a_baseline_package_runs_beside_this_tree_interleaved(tmp_path):
    import shutil

    baseline = tmp_path / "baseline"
    shutil.copytree(ROOT / "python" / "plantdreamer", baseline / "plantdreamer",
                    ignore=shutil.ignore_patterns("__pycache__"))  # fmt: skip
    out = tmp_path / "throughput.md"
    cmd = [
        sys.executable, "benches/bench_throughput.py", "--tiny", "--networks", "stub",
        "--groups", "2", "--overlap", "on", "--steps", "3", "--warmup", "1", "--points", "800",
        "--render", "32", "24", "--sds", "16", "--baseline", str(baseline), "--out", str(out),
    ]  # fmt: skip
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    rows = json.loads(out.with_suffix(".json").read_text())["groups"]
    assert list(rows) == [
        "2-overlap-r32-baseline", "2-overlap-r32", "2-overlap-r24-baseline", "2-overlap-r24",
    ]  # fmt: skip
    for label, row in rows.items():
        assert row["render"] == int(label.split("-r")[1].split("-")[0])
        assert row["build"] == ("baseline" if label.endswith("baseline") else "this")
        import plantdreamer

        this = Path(plantdreamer.__file__).parent
        expected = baseline / "plantdreamer" if row["build"] == "baseline" else this
        assert Path(row["package"]).resolve() == expected.resolve()
    assert "| baseline | 2 | 32 | on |" in out.read_text()


def test_the_raster_reference_renders_cameras_the_window_trained_on(tmp_path):
    """``window_cameras`` of a fresh plant are the cameras its guidance saw in the steady
    window's steps (recorded by a stub guidance during a real group run)."""
    from stub_guidance import StubGuidance

    from plant_runs import failed, group
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.settings.runtime import resolve_plants
    from plantdreamer.pipeline.state.run_state import RunState

    seen: dict[int, list] = {}

    class Recording(StubGuidance):
        def __call__(self, images, depth_cond, cameras, step):
            seen[step] = [c.viewmat.tobytes() for c in cameras]
            return super().__call__(images, depth_cond, cameras, step)

    cfgs = [
        GenerateConfig.of(
            species="bean", seed=s, steps=6, points=800, resolution=24, sds_resolution=16,
            eval_views=1, turntable_frames=1, turntable="none", checkpoint_every=6,
            device="cpu",
        )
        for s in range(2)
    ]  # fmt: skip
    result = group(cfgs, tmp_path, guidance=Recording(resolution=16), show_progress=False)
    assert not failed(result) and sorted(seen) == list(range(6))
    resolve_plants(cfgs)
    for k, cfg in enumerate(cfgs):
        sampler = RunState.fresh(cfg, show_progress=False).sampler
        picked = bench_throughput.window_cameras(sampler, 2, 5, 3)
        assert [c.viewmat.tobytes() for c in picked] == [seen[s][k] for s in (2, 4, 5)]
