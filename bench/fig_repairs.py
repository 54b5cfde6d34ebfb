"""Figures 15 and 16: what repairs cost a run, and `sensaov check` against `sensaov run`.

15: ``sensaov run`` of ``configs/interior.yaml`` as shipped (the default ``repair.budget``)
against the same job with ``repair.budget: 0``, whole processes interleaved; and whether the
repaired run's headline view (the ranked summary) shows any number not labelled verified.
16: ``sensaov check configs/cbox.yaml`` with the README's arguments (none) against ``sensaov
run configs/cbox.yaml`` (which writes the buffer the check's duality column reads), each run
followed by its check in the same round; and the check's progress lines.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path

from bench.jobs import REPO, Workspace
from bench.results import Figure, Goal, Row, fmt
from bench.settings import Settings
from bench.timing import ChildRun, Stats, interleave, timed_child

SENSAOV = str(Path(sys.executable).parent / "sensaov")
Log = Callable[[str], None]


def repair_cost(ws: Workspace, s: Settings, log: Log) -> Figure:
    figure = Figure(
        15,
        "Repairs: `sensaov run configs/interior.yaml` / the same without repairs",
        "≤ 2.0×; no unverified number in the summary",
        "Whole-process wall time of `sensaov run JOB -q --json` on a copy of "
        "configs/interior.yaml (outputs in the scratch directory, its forward group left out) "
        "with its default repair "
        "budget against the same job with `repair: {budget: 0}` (the run as it was before "
        "repairs), interleaved after one warm-up round. The summary check counts the ranked "
        "parameters, objects and types of every objective (the run's headline view) whose "
        "label is not `verified`.",
    )
    render = {"resolution": [32, 32], "spp": 8} if s.quick else {}
    config = REPO / "configs" / "interior.yaml"
    # Without the job's forward passes: the figure is about what repairs add to the adjoint run.
    repaired = ws.config_copy("repairs_on", config, render=render, forward=[])
    plain = ws.config_copy("repairs_off", config, render=render, repair={"budget": 0}, forward=[])
    runs: dict[str, list[ChildRun]] = {"on": [], "off": []}
    t = interleave(
        {
            "on": timed_child([SENSAOV, "run", str(repaired), "-q", "--json"], runs["on"]),
            "off": timed_child([SENSAOV, "run", str(plain), "-q", "--json"], runs["off"]),
        },
        s.process_rounds,
    )
    summary = json.loads(runs["on"][-1].stdout)
    figures = summary["provenance"].get("repairs", {})
    unverified = _unverified_rows(summary)
    figure.rows.append(
        Row(
            "run with repairs / without",
            t["on"].ratio_to(t["off"]),
            "x",
            Goal("<=", 2.0),
            f"{fmt(t['on'].median, 's')} vs {fmt(t['off'].median, 's')}; "
            f"{len(figures.get('repaired', []))} parameters repaired "
            f"({len(figures.get('seeds', []))} seeds x {figures.get('spp')} spp, "
            f"{figures.get('renders')} renders), "
            f"{len(figures.get('not_repaired', {}))} left labelled",
        )
    )
    figure.rows.append(
        Row(
            "summary rows not labelled verified, with repairs",
            Stats.of([len(unverified)]),
            "count",
            Goal("<=", 0),
            ", ".join(unverified) or "none",
        )
    )
    log("figure 15: done")
    return figure


def _unverified_rows(summary: dict) -> list[str]:
    found = []
    for objective in summary["objectives"]:
        for group, field in (("parameters", "key"), ("objects", "name"), ("types", "type")):
            found += [
                f"{objective['name']}/{row[field]}"
                for row in objective[group]
                if row["trust"] != "verified"
            ]
    return found


def check_cost(ws: Workspace, s: Settings, log: Log) -> Figure:
    figure = Figure(
        16,
        "`sensaov check configs/cbox.yaml` (the README's example) / `sensaov run` of it",
        "≤ 5×; progress printed",
        "Whole-process wall time of `sensaov check JOB` (the README's arguments: none) against "
        "`sensaov run JOB -q` on a copy of configs/cbox.yaml (outputs in the scratch directory; "
        "the check's duality column reads the run's buffer), each round a run then its check, "
        "after one warm-up round. The check's progress lines are counted on its stderr.",
    )
    render = {"resolution": [32, 32], "spp": 8} if s.quick else {}
    job = ws.config_copy("check_cbox", REPO / "configs" / "cbox.yaml", render=render)
    runs: dict[str, list[ChildRun]] = {"run": [], "check": []}
    t = interleave(
        {
            "run": timed_child([SENSAOV, "run", str(job), "-q"], runs["run"]),
            "check": timed_child(
                [SENSAOV, "check", str(job), "--progress", "plain"], runs["check"]
            ),
        },
        s.process_rounds,
    )
    figure.rows.append(
        Row(
            "check / run",
            t["check"].ratio_to(t["run"]),
            "x",
            Goal("<=", 5.0),
            f"{fmt(t['check'].median, 's')} vs {fmt(t['run'].median, 's')}",
        )
    )
    stderr = runs["check"][-1].stderr.splitlines()
    progress = sum(line.startswith("sensaov: check:") for line in stderr)
    figure.rows.append(
        Row(
            "progress lines of one check",
            Stats.of([progress]),
            "count",
            Goal(">=", 1),
            "lines 'sensaov: check: …' on stderr, one per render",
        )
    )
    log("figure 16: done")
    return figure
