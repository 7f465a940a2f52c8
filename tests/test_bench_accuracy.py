"""benches/bench_accuracy.py's table and findings: computed from the results they are
given (synthetic curves here), never typed in."""

import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benches"))

import bench_accuracy  # noqa: E402


def _run(config: str, seed: int, psnr: dict[int, float], gaussians: int = 100, secs: float = 1.0,
         models: str = "version 6, VAE 1600 steps") -> dict[str, Any]:  # fmt: skip
    curve = [{"steps": s, "masked_psnr": v, "seconds": secs * max(s, 1) / 100,
              "gaussians": gaussians} for s, v in sorted(psnr.items())]  # fmt: skip
    return {"seed": seed, "resolution": 64, "models": models, "config": config, "curve": curve}


def test_findings_read_the_plateau_densification_and_groups_from_the_results() -> None:
    long_ = {0: 10.0, 100: 13.0, 200: 15.0, 400: 15.1, 600: 15.2}
    results = [
        _run("noise, CFG 100, no densify", s, {k: v + s for k, v in long_.items()}) for s in (0, 1)
    ]
    for s in (0, 1):
        densified = {k: v + s - (0.5 if k == 600 else 0) for k, v in long_.items()}
        results.append(_run("noise, CFG 100, densify", s, densified, gaussians=300, secs=1.5))
    short = {0: 10.0, 50: 11.0, 100: 12.0, 200: 13.0}
    results += [_run("noise, CFG 100", s, short) for s in (0, 1)]
    results += [
        _run("noise, CFG 100, group of 2", s, {k: v - 0.3 * (k == 50) for k, v in short.items()})
        for s in (0, 1)
    ]
    found = "\n".join(bench_accuracy.findings(results))
    print(found)
    assert "stops rising (under 0.25 dB to the next point) after 200 steps" in found
    assert (
        "Densification (64 px, version 6, VAE 1600 steps, 600 steps, 2 seeds): 300 Gaussians against 100"
        in found
    )
    assert "-0.50 to -0.50 dB against none, in 1.50-1.50 times the seconds" in found
    assert "A group of 2 (64 px, version 6, VAE 1600 steps, 2 seeds): within 0.30 dB" in found
    assert "bfloat16" not in found  # not measured, so not claimed
    table = bench_accuracy.table(results)
    assert (
        "| noise, CFG 100, no densify | 64 | version 6, VAE 1600 steps | 2 | 10.50 ± 0.50 |"
        in table
    )


def test_runs_of_different_model_sets_are_rows_of_their_own_and_never_paired() -> None:
    """A table can hold rows measured with an older recipe (not every row was measured
    again): they get a row of their own and are never compared with the new ones."""
    short = {0: 10.0, 50: 11.0, 100: 12.0, 200: 13.0}
    old = "version 6, VAE 800 steps"
    results = [_run("noise, CFG 100", 0, short)]
    results.append(_run("noise, CFG 100, group of 2", 0, {k: v - 2 for k, v in short.items()},
                        models=old))  # fmt: skip
    found = "\n".join(bench_accuracy.findings(results))
    assert "group of 2" not in found  # no plain run of the old set to compare with
    results.append(_run("noise, CFG 100", 0, {k: v - 1.5 for k, v in short.items()}, models=old))
    found = "\n".join(bench_accuracy.findings(results))
    assert f"A group of 2 (64 px, {old}, 1 seeds): within 0.50 dB" in found
    table = bench_accuracy.table(results)
    assert "| noise, CFG 100 | 64 | version 6, VAE 1600 steps | 1 | 10.00 |" in table
    assert f"| noise, CFG 100 | 64 | {old} | 1 | 8.50 |" in table


def test_a_gap_under_half_a_hundredth_is_not_printed_as_zero() -> None:
    short = {0: 10.0, 50: 11.0, 100: 12.0, 200: 13.0}
    results = [_run("noise, CFG 100", 0, short)]
    results.append(_run("noise, CFG 100, VAE float16", 0, {k: v + 0.001 for k, v in short.items()}))
    found = "\n".join(bench_accuracy.findings(results))
    assert (
        "The VAE in float16 (64 px, version 6, VAE 1600 steps, 1 seeds): within 0.005 dB" in found
    )


def test_the_plot_shows_at_most_six_runs_and_the_table_gives_them_back() -> None:
    """The plot's figures are the table's: read back from the written table (`--replot`),
    they are those computed from the results, for at most six runs of the first set."""
    short = {0: 10.0, 50: 11.0, 100: 12.0, 200: 13.0}
    results = [
        _run(name, s, {k: v + s + i for k, v in short.items()}, secs=1.0 + i)
        for i, (name, _, curve) in enumerate(bench_accuracy.CONFIGS)
        if curve == bench_accuracy.SHORT
        for s in (0, 1)
    ]
    results.append(_run("noise, CFG 100", 0, short, models="version 6, VAE 800 steps"))
    title, computed = bench_accuracy.curves(results)
    assert len(computed) == len(bench_accuracy.PLOTTED) <= 6
    assert {c[0] for c in computed} == set(bench_accuracy.PLOTTED)
    assert bench_accuracy.curves_from_table(bench_accuracy.table(results)) == (
        title,
        [(n, st, [round(m, 2) for m in ms], round(p, 1)) for n, st, ms, p in computed],
    )
