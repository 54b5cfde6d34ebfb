"""``python -m bench``: run every figure, print the table, write ``bench/results.md``."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from bench import (
    fig_batches,
    fig_buffer,
    fig_farm,
    fig_forward,
    fig_interior,
    fig_objectives,
    fig_passes,
    fig_process,
    fig_project,
    fig_repairs,
    fig_texels,
    fig_view,
    machine,
    settings,
)
from bench.jobs import REPO, Workspace
from bench.results import Figure, console_table, markdown

HERE = Path(__file__).resolve().parent


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument(
        "--quick",
        action="store_true",
        help="tiny sizes and 2 rounds, to check the suite runs (writes "
        "bench/results-quick.md unless --out is given)",
    )
    parser.add_argument(
        "--variant",
        default="auto",
        help="Mitsuba variant of every job: auto (default), llvm_ad_rgb, cuda_ad_rgb",
    )
    parser.add_argument("--only", default="", help="comma-separated figure numbers, e.g. 2,3")
    parser.add_argument("--out", type=Path, help="where to write the results (markdown)")
    return parser.parse_args(argv)


class Log:
    def __init__(self) -> None:
        self.start = time.perf_counter()

    def __call__(self, message: str) -> None:
        print(
            f"[bench {time.perf_counter() - self.start:6.1f} s] {message}",
            file=sys.stderr,
            flush=True,
        )


def resolve_variant(variant: str) -> tuple[str, str]:
    """The concrete variant ``auto`` stands for here, and the libLLVM it uses (if any).

    Importing through sensaov also sets ``DRJIT_LIBLLVM_PATH`` for the child processes.
    """
    from sensaov_cli.render.runtime import import_mitsuba

    mi = import_mitsuba(variant)
    import drjit as dr

    llvm = ""
    if mi.variant().startswith("llvm"):
        llvm = ".".join(map(str, dr.detail.llvm_version()))
        llvm += f" ({os.environ.get('DRJIT_LIBLLVM_PATH', '')})"
    return mi.variant(), llvm


def plan(
    ws: Workspace, s: settings.Settings, concrete: str, log: Log
) -> list[tuple[int, Callable[[], list[Figure]]]]:
    """Figures in the order they run; 8 is computed from the passes timed for 2 and 3."""
    passes: list[fig_passes.PassTimes] = []

    def cost() -> list[Figure]:
        figure, measured = fig_passes.adjoint_cost(ws, s, log)
        passes.extend(measured)
        return [figure]

    def texture() -> list[Figure]:
        figure, measured = fig_passes.texture_independence(ws, s, log)
        passes.extend(measured)
        return [figure]

    return [
        (1, lambda: [fig_process.pipeline_overhead(ws, s, concrete, log)]),
        (2, cost),
        (3, texture),
        (4, lambda: [fig_project.reprojection(ws, s, log)]),
        (5, lambda: [fig_objectives.objectives_cost(ws, s, log)]),
        (6, lambda: [fig_process.memory(ws, s, concrete, log)]),
        (7, lambda: [fig_process.startup(ws, s, log)]),
        (8, lambda: [fig_passes.finite_differences(passes)] if passes else []),
        (9, lambda: [fig_buffer.buffer_io(ws, s, log)]),
        (10, lambda: [fig_farm.farm(ws, s, log)]),
        (11, lambda: [fig_forward.forward_cost(ws, s, log)]),
        (12, lambda: [fig_texels.texel_cost(ws, s, log)]),
        (13, lambda: [fig_view.view_latency(ws, s, log)]),
        (14, lambda: [fig_interior.interior(ws, s, log)]),
        (15, lambda: [fig_repairs.repair_cost(ws, s, log)]),
        (16, lambda: [fig_repairs.check_cost(ws, s, log)]),
        (17, lambda: [fig_batches.batches_cost(ws, s, log)]),
    ]


def run_figures(
    steps: list[tuple[int, Callable[[], list[Figure]]]], only: set[int], log: Log
) -> list[Figure]:
    figures = []
    for number, step in steps:
        if only and number not in only:
            continue
        try:
            figures += step()
        except Exception as error:  # noqa: BLE001 - one broken figure must not hide the others
            traceback.print_exc()
            figures.append(Figure(number, f"figure {number}", "", "", error=f"{error!r}"[:300]))
            log(f"figure {number}: FAILED ({type(error).__name__})")
    return figures


def compile_package() -> None:
    """Write sensaov's bytecode before anything is timed, as ``pip install`` does for a user.

    The Makefile installs the package editable, and under ``PYTHONDONTWRITEBYTECODE`` (set on
    these shared machines) every process would compile its ~90 modules again: 0.06 s a
    process on 2 cores, which a user's installed tool never pays.
    """
    import compileall

    compileall.compile_dir(REPO / "sensaov_cli", quiet=1)


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    log = Log()
    compile_package()
    load_start, sources_start = os.getloadavg()[0], machine.source_digest(REPO)
    concrete, llvm = resolve_variant(args.variant)
    s = (settings.quick if args.quick else settings.full)(args.variant)
    only = {int(n) for n in args.only.split(",") if n.strip()}
    log(f"{'quick' if args.quick else 'full'} run, variant {concrete}")
    with tempfile.TemporaryDirectory(prefix="sensaov-bench-") as scratch:
        ws = Workspace(Path(scratch), args.variant)
        figures = run_figures(plan(ws, s, concrete, log), only, log)
    wall = time.perf_counter() - log.start
    print(console_table(figures))
    command = "python -m bench " + " ".join(argv if argv is not None else sys.argv[1:])
    run = machine.RunInfo(
        concrete,
        llvm,
        (load_start, os.getloadavg()[0]),
        (sources_start, machine.source_digest(REPO)),
        wall,
        command.strip(),
    )
    out = args.out or HERE / ("results-quick.md" if args.quick else "results.md")
    out.write_text(markdown(figures, machine.header(REPO, run), s.describe()))
    log(f"wrote {out} ({wall / 60:.1f} min)")
    if run.sources[0] != run.sources[1]:
        log("warning: sources changed during the run; the figures mix code versions")
    return 1 if any(f.error for f in figures) else 0
