"""Figure 13: ``sensaov view``'s latency per view, warm, and what one view costs over its trace."""

from __future__ import annotations

import math
import threading
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

from bench import notes
from bench.fig_project import _make_buffer
from bench.jobs import EXTRA_OBJECTIVES, MEAN_LUMA, SCENES, Workspace
from bench.results import Figure, Goal, Row, fmt
from bench.settings import Settings
from bench.timing import Stats, synced

BUFFER_SPP = 8  # the buffer's quality does not change what painting it costs
LATENCY_GOAL_S = 0.150  # the goal per view at 256², 1 spp, on 2 CPU cores


def view_latency(ws: Workspace, s: Settings, log: Callable[[str], None]) -> Figure:
    side, views = s.live_view, s.live_views
    figure = Figure(
        13,
        f"Live view (`sensaov view`): latency per view at {side}², 1 spp, warm",
        f"≤ {LATENCY_GOAL_S * 1000:.0f} ms per view (median and 95th percentile)",
        f"The real server (`live/server.py`, in this process, on a loopback port) "
        f"answers `GET /api/view` for the `objects` channel of cbox (two objectives, buffer at "
        f"{BUFFER_SPP} spp) at {side}², 1 spp, PNG, from {views} cameras along an orbit, each "
        "new (no view is served from the cache); the time is the HTTP round trip from request "
        "to the last byte (urllib), after one untimed view that compiles the kernel. Each view "
        "alternates with the bare primary-visibility pass of `sensaov project` "
        f"(`render.visibility.trace` on a fixed {side}² sensor, 1 spp), and the ratio is taken "
        "per pair. Kernel compilations over the timed views are counted from Dr.Jit's kernel "
        "history. The machine is shared by five engineers: read ratios, not absolute times.",
    )
    figure.why_missed = notes.LIVE_VIEW
    job = ws.job(
        "live_cbox",
        SCENES["cbox"],
        resolution=s.resolutions[0],
        spp=BUFFER_SPP,
        objectives=[MEAN_LUMA, EXTRA_OBJECTIVES[0]],
        inspection=({"name": "fixed", "look_at": _orbit(0.0), "fov": 40, "resolution": [side, side],
                     "vis_spp": 1},),
    )  # fmt: skip
    buffer_path = _make_buffer(job)
    http, trace, compiles, first = _measure(job, buffer_path, side, views)
    log("figure 13: done")
    figure.rows += _rows(side, http, trace, compiles, first)
    return figure


def _measure(
    job: Path, buffer_path: Path, side: int, views: int
) -> tuple[Stats, Stats, int, float]:
    import drjit as dr

    from sensaov_cli.job.load import load_job
    from sensaov_cli.live.server import ViewServer
    from sensaov_cli.live.session import open_session
    from sensaov_cli.progress import Progress
    from sensaov_cli.render.visibility import trace

    spec = load_job(job)
    progress = Progress(quiet=True)
    session = open_session(spec, buffer_path=buffer_path, force=False, progress=progress)
    first = progress.timings["warm_s"]  # the kernel compilation a fresh process pays once
    loaded = session.loaded
    sensor = loaded.inspection_sensors["fixed"]
    server = ViewServer(("127.0.0.1", 0), lambda text: None, None)
    server.attach(session)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05})
    thread.start()
    try:
        get = _getter(server.url, side)

        def bare_trace() -> float:
            mi, scene, objects = loaded.mi, loaded.scene, loaded.objects
            return float(synced(lambda: trace(mi, scene, sensor, objects, 1))[0])

        get(-1)  # untimed
        bare_trace()
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        http, bare = [], []
        for index in range(views):
            http.append(get(index))
            bare.append(bare_trace())
        compiled = [k for k in dr.kernel_history() if "cache_hit" in k and not k["cache_hit"]]
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    finally:
        server.shutdown()
        server.server_close()
        thread.join()
    # the bare trace's own kernel is compiled once before timing; any later compile is the view's
    return Stats.of(http), Stats.of(bare), len(compiled), first


def _getter(url: str, side: int) -> Callable[[int], float]:
    def get(index: int) -> float:
        look = _orbit(0.1 * (index + 1))
        camera = ",".join(map(str, look["origin"]))
        query = f"api/view?channel=objects&origin={camera}&width={side}&height={side}&spp=1"
        start = time.perf_counter()
        with urllib.request.urlopen(url + query, timeout=60) as answer:
            answer.read()
        return time.perf_counter() - start

    return get


def _orbit(angle: float) -> dict[str, list[float]]:
    """A camera on a circle around the box, 3.9 from its centre, looking at it."""
    origin = [3.9 * math.sin(angle), 0.4, 3.9 * math.cos(angle)]
    return {"origin": origin, "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0]}


def _rows(side: int, http: Stats, bare: Stats, compiles: int, first: float) -> list[Row]:
    ordered = sorted(http.values)
    p95 = ordered[min(len(ordered) - 1, math.ceil(0.95 * len(ordered)) - 1)]
    goal = Goal("<=", LATENCY_GOAL_S)
    case = f"cbox {side}², 1 spp, warm"
    return [
        Row(f"{case}, HTTP round trip, median", http, "s", goal,
            f"p95 {fmt(p95, 's')}, n = {http.n} views, each a new camera"),
        Row(f"{case}, HTTP round trip, 95th percentile", Stats.of([p95]), "s", goal,
            f"of the same {http.n} views"),
        Row(f"{case}, one view / the bare visibility trace", http.ratio_to(bare), "x", None,
            f"trace {fmt(bare.median, 's')} median (project's pass, fixed camera)"),
        Row(f"{case}, kernels compiled while the camera moved", Stats.of([compiles]), "count",
            Goal("<=", 0), "a moved camera must reuse the compiled kernel"),
        Row("start-up warm-up of a fresh session (2 kernels)", Stats.of([first]), "s", None,
            "compiled, or read from Dr.Jit's disk cache; paid once while `sensaov view` starts"),
    ]  # fmt: skip
