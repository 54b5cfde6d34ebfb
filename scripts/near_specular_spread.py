"""Reverse mode against central differences on a near-specular rough dielectric, by roughness.

tests/scenes/near_specular.xml's glass ball has a roughness checkerboard whose ``color0`` is
set here to each ``--roughness``; per seed, η's adjoint <∂M/∂η, 1> from a primal and a prb
backward pass (as ``sensaov run`` computes it) and the central difference of M with common
random numbers (ε = 0.01, as a repair takes it) at the same seed. Prints, per roughness, the
mean, standard error and range of each, and whether ``statistics.heavy_tail`` calls the
seeds' estimates heavy-tailed: the evidence behind render/verify/tails.py's threshold
(docs/verification.md, "Heavy tails").

    .venv/bin/python scripts/near_specular_spread.py       # about a minute on 2 cores
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from sensaov_cli.buffer.statistics import heavy_tail
from sensaov_cli.job.load import load_job
from sensaov_cli.render.loading import assign, load_job_scene
from sensaov_cli.render.objectives import build_objectives
from sensaov_cli.render.verify.fdcheck import adjoint_along, central_difference, direction

REPO = Path(__file__).resolve().parent.parent
JOB = f"""version: 1
scene: {REPO / "tests/scenes/near_specular.xml"}
variant: llvm_ad_rgb
render: {{spp: 16, seed: 0, resolution: [16, 16]}}
objectives: [{{name: mean_luma, type: mean_luminance}}]
output: out
"""
ETA, ALPHA0 = "glass_ball.bsdf.eta", "glass_ball.bsdf.alpha.color0.value"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--roughness", type=float, nargs="*", default=[0.0, 0.01, 0.02, 0.05])
    parser.add_argument("--seeds", type=int, default=16)
    parser.add_argument("--spp", type=int, default=16)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "job.yaml").write_text(JOB)
        spec = load_job(Path(tmp) / "job.yaml")
        loaded = load_job_scene(spec)
    (objective,) = build_objectives(loaded.mi, spec.objectives, (16, 16), False)
    info = next(r for r in loaded.selected if r.key == ETA)
    print(f"{args.seeds} seeds x {args.spp} spp, 16x16, mean luminance; ∂M/∂η of {ETA}")
    print("| roughness color0 | estimator | mean | std. err. | min | max | heavy_tail |")
    print("|---|---|---|---|---|---|---|")
    for roughness in args.roughness:
        assign(loaded, ALPHA0, np.full((1,), roughness, np.float32))
        seeds = range(args.seeds)
        adjoints = [adjoint_along(loaded, objective, info, direction(info), args.spp, s)
                    for s in seeds]  # fmt: skip
        differences = [central_difference(loaded, objective, info, 0.01, args.spp, (s, s))
                       for s in seeds]  # fmt: skip
        for name, values in (("reverse (prb)", adjoints), ("central differences", differences)):
            x = np.array(values)
            flag = "fires" if heavy_tail(x) else "-"
            print(f"| {roughness:g} | {name} | {x.mean():+.3e} | "
                  f"{x.std(ddof=1) / np.sqrt(len(x)):.1e} | {x.min():+.2e} | {x.max():+.2e} "
                  f"| {flag} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
