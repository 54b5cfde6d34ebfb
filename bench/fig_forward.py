"""Figure 11: a forward channel's and a transport layer's cost, against one backward pass."""

from __future__ import annotations

import time
from functools import partial
from typing import Any

import numpy as np

from bench.fig_passes import GRAD_SEED, Log, Passes
from bench.jobs import SCENES, Workspace
from bench.results import Figure, Row, fmt
from bench.settings import Settings
from bench.timing import interleave, synced


def forward_cost(ws: Workspace, s: Settings, log: Log) -> Figure:
    figure = Figure(
        11,
        "Forward channels: one forward pass / one backward pass (report)",
        "report (MITSUBA-NOTES: render_forward ≈ 3× a primal, a backward pass ≈ 2×)",
        "In-process, interleaved, `dr.sync_thread()` around each, all threads: the backward "
        "pass of every selected parameter (`adjoint.backward`) vs `render.adjoint."
        "forward_image` of one pushed reflectance (direction θ, the image read back to numpy) "
        "vs a transport layer (the same forward pass plus T_p = Σ_c dM/dI · J·v and its sum, "
        f"numpy). {s.resolutions[0]}², {s.spp} spp, the same seed.",
    )
    res = s.resolutions[0]
    for scene in SCENES:
        passes = Passes.load(ws.job(f"fwd_{scene}_{res}", SCENES[scene], resolution=res, spp=s.spp))
        key = next(i.key for i in passes.loaded.selected if i.type == "reflectance")
        adjoint = np.array(passes.adjoint, np.float64)
        t = interleave(
            {
                "backward": passes.backward,
                "forward": partial(_forward_seconds, passes, key),
                "transport": partial(_transport, passes, key, adjoint),
            },
            s.rounds,
        )
        case = f"{scene} {res}²"
        figure.rows += [
            Row(
                f"{case}, forward channel",
                t["forward"].ratio_to(t["backward"]),
                "x",
                None,
                f"forward {fmt(t['forward'].median, 's')}, backward "
                f"{fmt(t['backward'].median, 's')} ({len(passes.loaded.selected)} parameters), "
                f"pushed {key}",
            ),
            Row(
                f"{case}, transport layer",
                t["transport"].ratio_to(t["backward"]),
                "x",
                None,
                f"transport {fmt(t['transport'].median, 's')}",
            ),
        ]
        log(f"figure 11: {scene} done")
    return figure


def _forward_seconds(passes: Passes, key: str) -> float:
    return float(_forward(passes, key)[0])


def _forward(passes: Passes, key: str) -> tuple[float, Any]:
    from sensaov_cli.render.adjoint import forward_image

    info = next(i for i in passes.loaded.selected if i.key == key)
    theta = np.array(passes.loaded.params[key], np.float32).reshape(info.shape)
    shape = tuple(passes.adjoint.shape)
    return synced(
        lambda: forward_image(
            passes.loaded, {key: theta}, spp=passes.spp, seed=GRAD_SEED, shape=shape,
            deterministic=False,
        )
    )  # fmt: skip


def _transport(passes: Passes, key: str, adjoint: np.ndarray) -> float:
    seconds, result = _forward(passes, key)
    began = time.perf_counter()
    per_pixel = (adjoint * result.image.astype(np.float64)).sum(axis=2)
    float(per_pixel.sum())
    return seconds + time.perf_counter() - began
