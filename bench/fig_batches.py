"""Figure 17: error bars by default: `sensaov run` with `render.batches: auto` / `batches: 1`.

The default splits render.spp into 8 batches (docs/job-spec.md) so that every buffer has
standard errors; each batch is a primal and backward passes of spp/8 samples at seeds of its
own, and forward channels are pushed per batch. Kernels are compiled once per configuration
and reused by every batch, so the split should cost little beyond its kernels' fixed cost.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from bench import notes
from bench.jobs import REPO, Workspace
from bench.results import Figure, Goal, Row, fmt
from bench.settings import Settings
from bench.timing import ChildRun, interleave, timed_child

SENSAOV = str(Path(sys.executable).parent / "sensaov")
Log = Callable[[str], None]


def batches_cost(ws: Workspace, s: Settings, log: Log) -> Figure:
    figure = Figure(
        17,
        "Error bars by default: `sensaov run` with `batches: auto` / `batches: 1`",
        "≤ 1.05×",
        "Whole-process wall time of `sensaov run JOB -q` on copies of configs/cbox.yaml (the "
        "job of `make demo`: two objectives, forward channels and transport layers, repairs) "
        "and configs/interior.yaml as shipped (their render.spp and resolution), with the "
        "default `render.batches` (auto: 8 batches, standard errors) against the same job "
        "with `batches: 1` (one pass, no errors) at the same spp, interleaved after one "
        "warm-up round.",
    )
    figure.why_missed = notes.BATCHES
    render = {"resolution": [32, 32], "spp": 8} if s.quick else {}
    for name in ("cbox", "interior"):
        config = REPO / "configs" / f"{name}.yaml"
        auto = ws.config_copy(f"batches_auto_{name}", config, render=render)
        one = ws.config_copy(f"batches_one_{name}", config, render={**render, "batches": 1})
        runs: dict[str, list[ChildRun]] = {"auto": [], "one": []}
        t = interleave(
            {
                "auto": timed_child([SENSAOV, "run", str(auto), "-q"], runs["auto"]),
                "one": timed_child([SENSAOV, "run", str(one), "-q"], runs["one"]),
            },
            s.process_rounds,
        )
        figure.rows.append(
            Row(
                f"configs/{name}.yaml: batches auto / 1",
                t["auto"].ratio_to(t["one"]),
                "x",
                Goal("<=", 1.05),
                f"{fmt(t['auto'].median, 's')} vs {fmt(t['one'].median, 's')}",
            )
        )
        log(f"figure 17: {name} done")
    return figure
