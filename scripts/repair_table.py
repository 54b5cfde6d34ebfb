"""Measure the repair rows of docs/verification.md: sensaov's repairs against central differences.

`sensaov run` on tests/scenes/repair_mix.xml (every kind Mitsuba 3.9.1 gets wrong that run
repairs: roughplastic α and η, smooth plastic, a blend over a smooth conductor, a reflectance
component exactly 0, the light's own reflectance 0), 32x32, two objectives, the repairs as a run
makes them (render.spp 16, repair.seeds 4, each kind's step). Each repaired component is then
compared with two references computed here, apart from the repair:

- common random numbers: central differences at 16 other seeds, 64 spp, twice the step;
- independent seeds: each side of the difference at seeds of its own, 2048 spp, 24 seeds.

    .venv/bin/python scripts/repair_table.py         # about 7 minutes on 2 quiet cores
    .venv/bin/python scripts/repair_table.py --independent-seeds 0   # CRN only, 1 minute

It prints the markdown that docs/verification.md holds: a row per component and objective,
then one label per kind: verified where every row is within 3 combined standard errors of both
references, else unverified. sensaov_cli/render/verify/trust.py's REPAIRS must say the same
(tests/test_trust.py compares them).
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import tempfile
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np
import yaml

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.job.load import load_job
from sensaov_cli.pipeline.run import run_job
from sensaov_cli.progress import Progress
from sensaov_cli.render.adjoint import render_primal
from sensaov_cli.render.loading import LoadedScene, assign, load_job_scene
from sensaov_cli.render.objectives import Objective, build_objectives, value_and_adjoint

SCENE = Path(__file__).resolve().parents[1] / "tests" / "scenes" / "repair_mix.xml"
RES, SPP, SEEDS = 32, 16, 4
CRN_SEEDS, CRN_SPP = range(5000, 5016), 64
IND_SPP = 2048
OBJECTIVES = [
    {"name": "mean_luma", "type": "mean_luminance"},
    {"name": "left", "type": "region_luminance", "region": [0.0, 0.2, 0.5, 0.9]},
]


def repaired_buffer(folder: Path) -> SensitivityBuffer:
    job = {
        "version": 1, "scene": str(SCENE), "variant": "llvm_ad_rgb",
        "render": {"spp": SPP, "max_depth": 5, "seed": 0, "resolution": [RES, RES]},
        "repair": {"budget": 100, "seeds": SEEDS}, "objectives": OBJECTIVES, "output": "out",
    }  # fmt: skip
    (folder / "job.yaml").write_text(yaml.safe_dump(job, sort_keys=False))
    spec = load_job(folder / "job.yaml")
    return run_job(spec, allow_python=False, progress=Progress(quiet=True))


class Reference:
    """Central differences of one component, apart from the repair."""

    def __init__(self, loaded: LoadedScene, objectives: list[Objective], key: str):
        self.loaded, self.objectives, self.key = loaded, objectives, key
        self.theta = np.array(loaded.params[key], dtype=np.float32).ravel()
        self.shape = next(r.shape for r in loaded.selected if r.key == key)

    def measure(self, c: int, offset: float, spp: int, seeds: list[int]) -> np.ndarray:
        """(seeds, objectives) M with component c moved by ``offset``."""
        moved = self.theta.copy()
        moved[c] += offset
        assign(self.loaded, self.key, moved.reshape(self.shape))
        try:
            return np.array([
                [value_and_adjoint(self.loaded.mi, o, render_primal(self.loaded, spp, s))[0]
                 for o in self.objectives]
                for s in seeds
            ])  # fmt: skip
        finally:
            assign(self.loaded, self.key, self.theta.reshape(self.shape))

    def difference(self, c: int, h: float, sign: int | None, spp: int, seeds: tuple) -> tuple:
        """Mean and standard error per objective; ``seeds``: one list, or one per side."""
        plus, minus, base = seeds if len(seeds) == 3 else (seeds[0], seeds[0], seeds[0])
        if sign is None:
            rows = (self.measure(c, h, spp, plus) - self.measure(c, -h, spp, minus)) / (2 * h)
        else:
            h *= sign
            rows = (4 * self.measure(c, h, spp, plus) - self.measure(c, 2 * h, spp, minus)
                    - 3 * self.measure(c, 0.0, spp, base)) / (2 * h)  # fmt: skip
        return rows.mean(axis=0), rows.std(axis=0, ddof=1) / np.sqrt(len(rows))


def rows_for(buffer: SensitivityBuffer, job: Path, independent: int) -> list[dict]:
    spec = load_job(job)
    loaded = load_job_scene(spec)
    objectives = build_objectives(loaded.mi, spec.objectives, (RES, RES), False)
    names = [o.spec.name for o in objectives]
    found = []
    for key, repair in buffer.repairs.items():
        ref, record = Reference(loaded, objectives, key), buffer.param(key)
        signs = dict(repair.one_sided)
        for c in range(repair.components):
            h = 2 * repair.step * max(1.0, abs(float(ref.theta[c])))
            crn = ref.difference(c, h, signs.get(c), CRN_SPP, (list(CRN_SEEDS),))
            ind = None
            if independent:  # each side (and a one-sided base) at seeds of its own
                sides = tuple(list(range(7000 + 1000 * i, 7000 + 1000 * i + independent))
                              for i in range(3))  # fmt: skip
                ind = ref.difference(c, h, signs.get(c), IND_SPP, sides)
            for j, name in enumerate(names):
                found.append({
                    "plugin": record.plugin, "type": record.type, "key": key, "c": c,
                    "objective": name, "reverse": repair.reverse[name][c],
                    "repair": repair.mean(name)[c], "se": repair.stderr(name)[c],
                    "crn": (crn[0][j], crn[1][j]),
                    "ind": None if ind is None else (ind[0][j], ind[1][j]),
                })  # fmt: skip
            print(f"measured {key}[{c}]", file=sys.stderr, flush=True)
    return found


def z(row: dict, reference: tuple[float, float] | None) -> float | None:
    if reference is None:
        return None
    return (row["repair"] - reference[0]) / float(np.hypot(row["se"], reference[1]) or 1e-30)


def line(row: dict) -> str:
    def ref(which: str) -> str:
        value = row[which]
        if value is None:
            return "not measured | "
        return f"{value[0]:+.3e} ± {value[1]:.1e} | {z(row, value):+.1f} "

    return (
        f"| {row['plugin']} | {row['type']} | `{row['key']}`[{row['c']}] | {row['objective']} | "
        f"{row['reverse']:+.3e} | {row['repair']:+.3e} ± {row['se']:.1e} | {ref('crn')}| "
        f"{ref('ind')}|"
    )


def labels(rows: list[dict]) -> dict[tuple[str, str], str]:
    found: dict[tuple[str, str], str] = {}
    for row in rows:
        kind = (row["plugin"], row["type"])
        ok = all(abs(v) <= 3 for v in (z(row, row["crn"]), z(row, row["ind"])) if v is not None)
        was = found.get(kind, "verified")
        found[kind] = "verified" if ok and was == "verified" else "unverified"
    return dict(sorted(found.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--independent-seeds", type=int, default=24)
    args = parser.parse_args()
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sensaov-repairs-") as tmp:
        buffer = repaired_buffer(Path(tmp))
        rows = rows_for(buffer, Path(tmp) / "job.yaml", args.independent_seeds)
    today = datetime.date.today().isoformat()
    print(
        f"Measured {today} with `scripts/repair_table.py`: Mitsuba {version('mitsuba')}, Dr.Jit "
        f"{version('drjit')}, llvm_ad_rgb, tests/scenes/repair_mix.xml at {RES}x{RES}; repairs "
        f"as run makes them ({SEEDS} seeds x {SPP} spp, each kind's step); references at twice "
        f"the step: common random numbers at {len(CRN_SEEDS)} other seeds x {CRN_SPP} spp, "
        f"independent seeds per side at {args.independent_seeds} seeds x {IND_SPP} spp. "
        f"{time.perf_counter() - start:.0f} s on {os.cpu_count()} CPU cores.\n"
    )
    print("| plugin | type | parameter[component] | objective | reverse mode | repair ± s.e. | "
          "CRN reference ± s.e. | z | independent ± s.e. | z |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(line(r) for r in rows))
    print("\nThe repairs' labels, per kind (verified: every row within 3 combined standard "
          "errors of both references):\n\n| plugin | type | label |\n|---|---|---|")  # fmt: skip
    print("\n".join(f"| {p} | {t} | {lab} |" for (p, t), lab in labels(rows).items()))


if __name__ == "__main__":
    main()
