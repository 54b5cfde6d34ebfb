"""Figure 5: what each extra objective costs, against one backward pass."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bench import notes
from bench.fig_passes import PRIMAL_SEED, Log, Passes
from bench.jobs import EXTRA_OBJECTIVES, MEAN_LUMA, SCENES, Workspace
from bench.results import Figure, Goal, Row, fmt
from bench.settings import Settings
from bench.timing import Stats, interleave, synced


def objectives_cost(ws: Workspace, s: Settings, log: Log) -> Figure:
    figure = Figure(
        5,
        "Objectives: cost of each extra objective / one backward pass",
        "≤ 1× (an extra objective costs at most one backward pass)",
        "In-process `run_adjoint` (the library's adjoint stage: one primal, then per objective "
        "dM/dI and one backward pass) with K = 1, 2, 4 objectives (mean luminance, two region "
        "luminances, an L2 to a grey target), interleaved; cost per extra objective = "
        "(T(K) − T(1)) / (K − 1), divided by the backward pass of the K = 1 run of the same "
        f"round. {s.resolutions[0]}², {s.spp} spp, all threads.",
    )
    figure.why_missed = notes.OBJECTIVES
    res = s.resolutions[0]
    target: dict[str, Any] = {
        "name": "match",
        "type": "l2_to_target",
        "target": str(ws.target_image(res)),
    }
    objectives: list[dict[str, Any]] = [MEAN_LUMA, *EXTRA_OBJECTIVES, target]
    for scene in SCENES:
        job = ws.job(
            f"obj_{scene}", SCENES[scene], resolution=res, spp=s.spp, objectives=objectives
        )
        passes = Passes.load(job)
        first_backward: list[float] = []
        sides = {str(k): _adjoint_stage(passes, k, first_backward) for k in (1, 2, 4)}
        t = interleave(sides, s.rounds)
        one = Stats.of(first_backward[-s.rounds :])
        figure.rows += [_extra_row(f"{scene} {res}²", k, t, one) for k in (2, 4)]
        log(f"figure 5: {scene} done")
    return figure


def _extra_row(case: str, k: int, t: dict[str, Stats], one: Stats) -> Row:
    """(T(K) − T(1)) / (K − 1) per round, over that round's backward pass."""
    totals = zip(t[str(k)].values, t["1"].values, strict=True)
    per_extra = Stats.of([(a - b) / (k - 1) for a, b in totals])
    return Row(
        f"{case}, K = 1 → {k}",
        per_extra.ratio_to(one),
        "x",
        Goal("<=", 1.0),
        f"T(1) {fmt(t['1'].median, 's')}, T({k}) {fmt(t[str(k)].median, 's')}, "
        f"backward {fmt(one.median, 's')}",
    )


def _adjoint_stage(passes: Passes, k: int, first_backward: list[float]) -> Callable[[], float]:
    from sensaov_cli.progress import Progress
    from sensaov_cli.render.adjoint import run_adjoint

    def measure() -> float:
        progress = Progress(quiet=True)
        seconds, _ = synced(
            lambda: run_adjoint(
                passes.loaded,
                passes.objectives[:k],
                spp=passes.spp,
                seed=PRIMAL_SEED,
                deterministic=False,
                progress=progress,
            )
        )
        if k == 1:
            name = passes.objectives[0].spec.name
            first_backward.append(progress.timings[f"backward_{name}_s"])
        return seconds

    return measure
