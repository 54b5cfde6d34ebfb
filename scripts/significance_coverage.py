"""Measure how often the truth falls inside a ranking's ± interval (docs/rankings.md).

For each scene: one reference buffer at many samples, then ``--seeds`` buffers of
``render.batches: 4`` at few samples, each at its own seed. For every ranked row (keys, objects,
types; untrusted parameters included, since the question is the noise, not the bias) it checks
whether the reference's signed sum lies within ``factor`` standard errors of the run's, for the
old rule (2 SE) and for Student's t at batches − 1 degrees of freedom. The reference's own noise
is small beside a run's (``--ref-spp`` / ``--spp`` = 64: its standard error is 1/8 of a run's).

    .venv/bin/python scripts/significance_coverage.py --seeds 48   # about 10 min on 2 cores

Prints a Markdown table. Not part of the test suite: it renders ~100 buffers.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np

from sensaov_cli.buffer.statistics import interval_factor
from sensaov_cli.job.load import load_job
from sensaov_cli.pipeline.run import run_job
from sensaov_cli.progress import Progress
from sensaov_cli.views.hierarchy import rankings

REPO = Path(__file__).resolve().parent.parent
SCENES = {"cbox": REPO / "configs/cbox.yaml", "interior": REPO / "configs/interior.yaml"}
BATCHES = 4


def signed_rows(job_path: Path, out: Path, spp: int, seed: int, batches: int) -> dict:
    """(cut, objective, name) -> (signed, signed_se) of one buffer rendered for the job."""
    job = load_job(job_path)
    render = dataclasses.replace(
        job.render, spp=spp, seed=seed, batches=batches, resolution=(64, 64)
    )
    job = dataclasses.replace(
        job, render=render, output=out, forward=(), channels=(), inspection_cameras=()
    )
    buffer = run_job(job, allow_python=False, progress=Progress(quiet=True))
    rows = {}
    for cut in ("key", "object", "type"):
        for ranking in rankings(buffer, by=cut, untrusted="include"):
            for row in ranking.rows:
                rows[(cut, ranking.objective, row.name)] = (row.signed, row.signed_se)
    return rows


def coverage(scene: str, seeds: int, spp: int, ref_spp: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        reference = signed_rows(SCENES[scene], Path(tmp) / "ref", ref_spp, 10_000, BATCHES)
        t = interval_factor(BATCHES)
        inside = {"2 SE": [], f"t = {t:.2f} SE": []}
        for seed in range(seeds):
            run = signed_rows(SCENES[scene], Path(tmp) / f"s{seed}", spp, seed, BATCHES)
            for at, (signed, se) in run.items():
                truth = reference[at][0]
                if not se or truth == 0.0:  # no gradient flows: nothing to cover
                    continue
                inside["2 SE"].append(abs(signed - truth) <= 2.0 * se)
                inside[f"t = {t:.2f} SE"].append(abs(signed - truth) <= t * se)
            print(f"{scene}: seed {seed + 1}/{seeds}", file=sys.stderr, flush=True)
    return {rule: float(np.mean(hits)) for rule, hits in inside.items()} | {
        "rows": float(len(inside["2 SE"]))
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=48)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--ref-spp", type=int, default=1024)
    args = parser.parse_args()
    print(f"| scene | rows (row × seed) | inside ±2 SE | inside ±t SE (t = "
          f"{interval_factor(BATCHES):.2f}, {BATCHES - 1} dof) |")  # fmt: skip
    print("|---|---|---|---|")
    for scene in SCENES:
        found = coverage(scene, args.seeds, args.spp, args.ref_spp)
        rules = [k for k in found if k != "rows"]
        print(f"| {scene} | {int(found['rows'])} | {100 * found[rules[0]]:.1f} % | "
              f"{100 * found[rules[1]]:.1f} % |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
