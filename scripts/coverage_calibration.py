"""Calibration of the default error bars: how often the truth falls outside a run's 95 % interval.

For each scene: one reference buffer at many more samples (``--ref-factor`` times the runs', its
own seed, 16 batches, ``repair.budget`` 50 so that it repairs whatever a run does), then
``--seeds`` runs of ``render.batches: 8`` at ``--spp``, each at its own seed. For every
parameter and objective (repaired parameters included: their batches are their repair's seeds)
the run's signed sum Σ θ·∂M/∂θ has the interval ± t(0.975, 7) · its standard error; the row
misses when the reference's signed sum lies outside it. Rows whose run left a repair out (over
its budget) are counted apart: their reference is another estimator. Rows are split by whether
``statistics.heavy_tail`` calls the run's 8 batch estimates heavy-tailed (the views' ``noisy``
label): the interval is claimed only for rows not flagged. The flag rate on the tame scenes is
its false-alarm rate in practice.

Scenes: scenes/cbox (diffuse, area light, a rough dielectric), scenes/interior (roughplastic
repairs, textures, a rough conductor), tests/scenes/near_specular.xml (a rough dielectric whose
roughness checkerboard has texels at 0, a medium with an albedo channel at 0); the last also with
``repair.budget: 0`` (reverse mode kept everywhere), to see what the flag does where repairs do
not step in. Images are ``--size`` pixels square (16 by default).

    .venv/bin/python scripts/coverage_calibration.py --seeds 40   # ~20 min on 2 shared cores
    .venv/bin/python scripts/coverage_calibration.py --seeds 40 --spp 128 --size 32 \
        --ref-factor 32 --scenes cbox near_specular interior        # ~35 min

Prints one Markdown table (and, with ``--rows FILE``, writes every row as CSV).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.statistics import SUM_VALUE, heavy_tail, interval_factor, pooled_stderr
from sensaov_cli.job.load import load_job
from sensaov_cli.job.spec import JobSpec
from sensaov_cli.pipeline.run import run_job
from sensaov_cli.progress import Progress

REPO = Path(__file__).resolve().parent.parent
BATCHES = 8
REF_BATCHES = 16
REF_BUDGET = 50.0
JOB = """version: 1
scene: {scene}
variant: llvm_ad_rgb
render: {{spp: 16, seed: 0, resolution: [{size}, {size}]}}
objectives:
  - {{name: mean_luma, type: mean_luminance}}
  - {{name: centre, type: region_luminance, region: [0.3, 0.3, 0.7, 0.7]}}
repair: {{budget: {budget}}}
output: out
"""
SCENES = {
    "cbox": (REPO / "scenes/cbox/scene.xml", 1.0),
    "interior": (REPO / "scenes/interior/scene.xml", 1.0),
    "near_specular": (REPO / "tests/scenes/near_specular.xml", 1.0),
    "near_specular, repair.budget 0": (REPO / "tests/scenes/near_specular.xml", 0.0),
}


@dataclasses.dataclass(frozen=True)
class Row:
    """One parameter's signed sum for one objective: value, error, batch estimates."""

    signed: float
    se: float
    batches: tuple[float, ...]
    estimator: str


def job_for(scene: Path, budget: float, folder: Path, size: int) -> JobSpec:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "job.yaml").write_text(JOB.format(scene=scene, budget=budget, size=size))
    return load_job(folder / "job.yaml")


def rows_of(
    job: JobSpec, out: Path, spp: int, seed: int, batches: int, budget: float | None = None
) -> dict:
    """(objective, key) -> Row of one buffer rendered for ``job`` at ``spp`` and ``seed``
    (``budget``: another repair.budget than the job's)."""
    render = dataclasses.replace(job.render, spp=spp, seed=seed, batches=batches)
    repair = job.repair if budget is None else dataclasses.replace(job.repair, budget=budget)
    job = dataclasses.replace(
        job, render=render, repair=repair, output=out, forward=(), channels=(),
        inspection_cameras=(),
    )  # fmt: skip
    buffer = run_job(job, allow_python=False, progress=Progress(quiet=True))
    return _rows(buffer)


def _rows(buffer: SensitivityBuffer) -> dict:
    statistics = buffer.statistics
    assert statistics is not None, "a run of several batches has statistics"
    rows = {}
    for objective, sums in statistics.batch_sums.items():
        for index, param in enumerate(buffer.params):
            values = sums[index, :, SUM_VALUE]
            spp = np.asarray(statistics.spp, np.float64)
            signed = float((values * spp).sum() / spp.sum())
            se = float(pooled_stderr(values, statistics.spp))
            rows[(objective, param.key)] = Row(signed, se, tuple(values), param.estimator)
    return rows


def calibrate(name: str, seeds: int, spp: int, ref_factor: int, size: int, writer: Any) -> dict:
    scene, budget = SCENES[name]
    t = interval_factor(BATCHES)
    counts = {"rows": 0, "miss": 0, "flagged": 0, "flagged_miss": 0, "ref_ratio": [],
              "other_estimator": 0}  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        job = job_for(scene, budget, Path(tmp) / "job", size)
        started = time.perf_counter()
        # whatever a run repairs, the reference repairs too: a budget that leaves none out
        reference = rows_of(job, Path(tmp) / "ref", spp * ref_factor, 10_000, REF_BATCHES,
                            budget=None if budget == 0 else REF_BUDGET)  # fmt: skip
        print(f"{name}: reference in {time.perf_counter() - started:.0f} s", file=sys.stderr)
        for seed in range(seeds):
            run = rows_of(job, Path(tmp) / f"s{seed}", spp, seed, BATCHES)
            for at, row in run.items():
                truth = reference[at]
                if row.se == 0.0 and truth.signed == 0.0:  # no gradient flows: nothing to cover
                    continue
                if row.estimator != truth.estimator:  # a run's budget left a repair out
                    counts["other_estimator"] += 1
                    continue
                flag = heavy_tail(row.batches)
                miss = abs(row.signed - truth.signed) > t * row.se
                counts["rows"] += 1
                counts["miss"] += miss and flag is None
                counts["flagged"] += flag is not None
                counts["flagged_miss"] += miss and flag is not None
                if row.se > 0:
                    counts["ref_ratio"].append(truth.se / row.se)
                if writer is not None:
                    numbers = [row.signed, row.se, truth.signed, truth.se, int(miss)]
                    writer.writerow([name, seed, *at, row.estimator, *numbers, int(bool(flag))])
            took = time.perf_counter() - started
            print(f"{name}: seed {seed + 1}/{seeds} ({took:.0f} s)", file=sys.stderr, flush=True)
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--spp", type=int, default=32, help="per run (8 batches)")
    parser.add_argument("--ref-factor", type=int, default=64, help="reference spp / run spp")
    parser.add_argument("--size", type=int, default=16, help="image width and height")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--rows", type=Path, help="write every row to this CSV file")
    args = parser.parse_args()
    handle = args.rows.open("w", newline="") if args.rows else None
    writer = csv.writer(handle) if handle else None
    if writer is not None:
        writer.writerow(["scene", "seed", "objective", "key", "estimator", "signed", "se",
                         "reference", "reference_se", "outside", "flagged"])  # fmt: skip
    t = interval_factor(BATCHES)
    started = time.perf_counter()
    lines = [
        f"| scene | rows (parameter × objective × seed) | not flagged: truth outside ±{t:.2f} SE "
        "| flagged heavy-tailed | flagged: truth outside | reference SE / run SE (median) "
        "| left out: run's budget left a repair out |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in args.scenes:
        c = calibrate(name, args.seeds, args.spp, args.ref_factor, args.size, writer)
        kept = c["rows"] - c["flagged"]
        lines.append(
            f"| {name} | {c['rows']} | {c['miss']} of {kept} ({c['miss'] / max(kept, 1):.1%}) "
            f"| {c['flagged']} ({c['flagged'] / max(c['rows'], 1):.1%}) "
            f"| {c['flagged_miss']} of {c['flagged']} "
            f"| {float(np.median(c['ref_ratio'])) if c['ref_ratio'] else math.nan:.2f} "
            f"| {c['other_estimator']} |"
        )
    if handle is not None:
        handle.close()
    print(f"{args.seeds} seeds × {args.spp} spp in {BATCHES} batches per run, "
          f"{args.size}x{args.size}; "
          f"references at {args.spp * args.ref_factor} spp in {REF_BATCHES} batches; "
          f"{time.perf_counter() - started:.0f} s")  # fmt: skip
    print("\n".join(lines))


if __name__ == "__main__":
    main()
