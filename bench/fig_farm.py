"""Figure 10: farm scale: threads, the deterministic switch, sub-passes, and merging shards."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.fig_buffer import MB, make_buffer
from bench.fig_passes import PRIMAL_SEED, Passes
from bench.jobs import SCENES, Workspace
from bench.results import Figure, Row, fmt
from bench.settings import Settings
from bench.timing import interleave, synced
from sensaov_cli.buffer.npz import buffer_writer
from sensaov_cli.outputs.atomic import atomic_write


def farm(ws: Workspace, s: Settings, log: Callable[[str], None]) -> Figure:
    res, spp = s.resolutions[0], 2 * s.spp
    figure = Figure(
        10,
        "Farm scale: threads, deterministic, sub-passes, merge",
        "report (no goal)",
        f"In-process `run_adjoint` on cbox {res}² at {spp} spp, one objective (primal, backward, "
        "self-checks), sides interleaved: Dr.Jit with 1 thread vs all threads "
        "(`dr.set_thread_count`), `deterministic: true` vs `false`, and the default split into "
        "sub-passes (stop checks, float64 sums) vs one pass. Merge: `sensaov merge` in-process on "
        f"4 shard buffers of one {s.io_texture}² RGB texture each (value and gradient: "
        f"{2 * s.io_texture**2 * 3 * 4 / MB:.0f} MB a shard), writing the merged buffer with "
        "standard errors and its primal.",
    )
    passes = Passes.load(ws.job("farm", SCENES["cbox"], resolution=res, spp=spp))
    threads = _thread_counts()
    t = interleave(
        {
            "1 thread": _adjoint(passes, threads=1),
            "all threads": _adjoint(passes, threads=threads),
            "deterministic": _adjoint(passes, threads=threads, deterministic=True),
            "one pass": _adjoint(passes, threads=threads, subpasses=1),
        },
        s.rounds,
    )
    every = t["all threads"]
    figure.rows += [
        Row(
            f"{threads} threads vs 1 (deterministic: false, the default)",
            t["1 thread"].ratio_to(every),
            "x",
            None,
            f"speed-up; 1 thread {fmt(t['1 thread'].median, 's')}, "
            f"{threads} threads {fmt(every.median, 's')}",
        ),
        Row(
            "deterministic: true vs false",
            t["deterministic"].ratio_to(every),
            "x",
            None,
            f"{fmt(t['deterministic'].median, 's')} vs {fmt(every.median, 's')}",
        ),
        Row(
            f"default sub-passes ({_count(passes)}) vs one pass",
            every.ratio_to(t["one pass"]),
            "x",
            None,
            f"{fmt(every.median, 's')} vs {fmt(t['one pass'].median, 's')}: the price of stop "
            "checks and float64 sums between sub-passes",
        ),
    ]
    log("figure 10: passes done")
    merged = _merge(ws, s)
    figure.rows.append(merged)
    log("figure 10: merge done")
    return figure


def _thread_counts() -> int:
    import drjit as dr

    return int(dr.thread_count())


def _count(passes: Passes) -> int:
    from sensaov_cli.render.adjoint import SAMPLES_PER_SUBPASS, sample_chunks

    width, height = passes.loaded.resolution
    return len(sample_chunks(width * height, passes.spp, SAMPLES_PER_SUBPASS))


def _adjoint(
    passes: Passes, *, threads: int, deterministic: bool = False, subpasses: int | None = None
) -> Callable[[], float]:
    """``subpasses``: None for the default split, 1 for one pass."""
    import drjit as dr

    from sensaov_cli.progress import Progress
    from sensaov_cli.render import adjoint

    width, height = passes.loaded.resolution
    samples = width * height * passes.spp

    def measure() -> float:
        before, limit = dr.thread_count(), adjoint.SAMPLES_PER_SUBPASS
        dr.set_thread_count(threads)
        adjoint.SAMPLES_PER_SUBPASS = limit if subpasses is None else samples // subpasses
        try:
            seconds, _ = synced(
                lambda: adjoint.run_adjoint(
                    passes.loaded,
                    passes.objectives[:1],
                    spp=passes.spp,
                    seed=PRIMAL_SEED,
                    deterministic=deterministic,
                    progress=Progress(quiet=True),
                )  # fmt: skip
            )
        finally:
            dr.set_thread_count(before)
            adjoint.SAMPLES_PER_SUBPASS = limit
        return seconds

    return measure


def _merge(ws: Workspace, s: Settings) -> Row:
    from sensaov_cli.buffer.shards import batch_plan, pixels_digest
    from sensaov_cli.outputs.exr import write_exr
    from sensaov_cli.pipeline.merge import merge_files
    from sensaov_cli.progress import Progress

    folder = ws.root / "merge"
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    primal = {"Y": np.zeros((8, 8), np.float32)}
    for i, (spp, seed) in enumerate(batch_plan(64, 0, 4), 1):
        shard = make_buffer(s.io_texture)
        provenance = {  # what merge checks a shard records: its batch of the plan, its primal
            "job_hash": "bench", "scene_fingerprint": "bench", "spp": spp, "job_spp": 64,
            "primal_seed": seed, "resolution": [8, 8],
            "job": {"objectives": [{"name": "mean_luma"}], "render": {"spp": 64, "seed": 0}},
            "task": {"shard": {"index": i, "count": 4}, "objectives": None},
            "mitsuba_version": "bench", "drjit_version": "bench", "variant": "bench",
            "primal": {"file": f"primal.shard-{i}-of-4.exr", "sha256": pixels_digest(primal)},
        }  # fmt: skip
        grads = {"mean_luma": {k: g * (1 + 0.1 * i) for k, g in shard.grads["mean_luma"].items()}}
        shard = type(shard)(
            provenance, shard.objects, shard.params, shard.objectives, dict(shard.values), grads
        )
        path = folder / f"buffer.shard-{i}-of-4.npz"
        atomic_write(path, buffer_writer(shard))
        write_exr(path.with_name(f"primal.shard-{i}-of-4.exr"), primal, {})
        paths.append(path)
    size = paths[0].stat().st_size / MB

    def measure() -> float:
        start = time.perf_counter()
        merge_files(paths, folder / "buffer.npz", progress=Progress(quiet=True))
        return time.perf_counter() - start

    t = interleave({"merge": measure}, max(2, s.rounds // 2))
    out = Path(folder / "buffer.npz").stat().st_size / MB
    return Row(
        f"merge 4 shards of {size:.0f} MB",
        t["merge"],
        "s",
        None,
        f"{fmt(4 * size / t['merge'].median, 'MB/s')} read; merged file {out:.0f} MB "
        "(with standard errors)",
    )
