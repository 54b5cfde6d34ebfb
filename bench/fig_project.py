"""Figure 4: one inspection view painted from a stored buffer vs one adjoint pass."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench import notes
from bench.fig_passes import Passes
from bench.jobs import EXTRA_OBJECTIVES, MEAN_LUMA, OVERHEAD, SCENES, Workspace
from bench.results import Figure, Goal, Row, fmt
from bench.settings import Settings
from bench.timing import Stats, interleave, synced
from sensaov_cli.pipeline.project import DEFAULT_BEAUTY_SPP

BUFFER_SPP = 8  # the buffer's own quality does not change what projecting it costs
CAMERA = "inspect"


def reprojection(ws: Workspace, s: Settings, log: Callable[[str], None]) -> Figure:
    figure = Figure(
        4,
        "Re-projection vs re-differentiation: one `project` view / one adjoint pass",
        "≤ 1/20",
        f"In-process `project_job` on one inspection camera at {s.view}², {s.vis_spp} "
        "visibility spp, the three channel kinds (object, type, select) for two objectives, "
        "layered EXR written; its time is the `visibility_s` stage (trace, painting, display "
        "scales) plus `ProjectedView.seconds` (beauty, display layers, EXR); scene loading and "
        "reading the buffer excluded. Measured with the CLI default beauty pass "
        f"(`--beauty-spp {DEFAULT_BEAUTY_SPP}`) and without it (`--beauty-spp 0`), and "
        f"`visibility.trace` alone. The adjoint pass is one backward pass at {s.view}², all "
        f"threads, at {s.view_spp} spp (as many samples as the view traces) and at {s.job_spp} "
        "spp (what the example jobs in configs/ use). The objective camera row: a job whose only "
        f"view is the objective camera at {s.view}², whose default beauty is the run's own "
        "primal.exr; all six are interleaved.",
    )
    figure.why_missed = notes.PROJECTION
    for scene in SCENES:
        job = _projection_job(ws, s, scene)
        buffer_path = _make_buffer(job)
        adjoint = Passes.load(
            ws.job(f"proj_adj_{scene}", SCENES[scene], resolution=s.view, spp=s.view_spp)
        )
        adjoint_job = Passes.load(
            ws.job(f"proj_adj_job_{scene}", SCENES[scene], resolution=s.view, spp=s.job_spp)
        )
        objective_job = _objective_job(ws, s, scene)
        objective_buffer = _make_buffer(objective_job)
        t = interleave(
            {
                "beauty": _view(job, buffer_path, DEFAULT_BEAUTY_SPP),
                "no_beauty": _view(job, buffer_path, 0),
                "objective": _view(
                    objective_job, objective_buffer, DEFAULT_BEAUTY_SPP, "objective"
                ),
                "trace": _trace(job, s.vis_spp),
                "adjoint": adjoint.backward,
                "adjoint_job": adjoint_job.backward,
            },
            s.view_rounds,
        )
        figure.rows += _rows(f"{scene} {s.view}²", t, s)
        log(f"figure 4: {scene} done")
    return figure


def _projection_job(ws: Workspace, s: Settings, scene: str) -> Path:
    """A job with one 512² inspection camera; its own render settings only make the buffer."""
    return ws.job(
        f"proj_{scene}",
        SCENES[scene],
        resolution=s.resolutions[0],
        spp=BUFFER_SPP,
        objectives=[MEAN_LUMA, EXTRA_OBJECTIVES[0]],
        inspection=(_camera(scene, s),),
    )


def _objective_job(ws: Workspace, s: Settings, scene: str) -> Path:
    """A job whose only view is the objective camera at the view size: its beauty is the run's
    primal (pipeline/project.py), so the default view renders no path trace."""
    return ws.job(
        f"proj_objective_{scene}",
        SCENES[scene],
        resolution=s.view,
        spp=BUFFER_SPP,
        objectives=[MEAN_LUMA, EXTRA_OBJECTIVES[0]],
        inspection=({"name": "objective", "objective": True, "vis_spp": s.vis_spp},),
    )


def _camera(scene: str, s: Settings) -> dict[str, Any]:
    where: dict[str, Any] = (
        {"look_at": OVERHEAD, "fov": 50} if scene == "cbox" else {"sensor": "corner"}
    )
    return {"name": CAMERA, **where, "resolution": [s.view, s.view], "vis_spp": s.vis_spp}


def _rows(case: str, t: dict[str, Stats], s: Settings) -> list[Row]:
    adjoint = fmt(t["adjoint"].median, "s")
    rows = []
    for side, label in (
        ("beauty", f"default (beauty {DEFAULT_BEAUTY_SPP} spp)"),
        ("no_beauty", "visibility only (beauty 0)"),
    ):
        for reference, spp in (("adjoint", s.view_spp), ("adjoint_job", s.job_spp)):
            rows.append(
                Row(
                    f"{case}, {label}, vs backward at {spp} spp",
                    t[side].ratio_to(t[reference]),
                    "x",
                    Goal("<=", 1 / 20, "1/20"),
                    f"view {fmt(t[side].median, 's')} vs backward {fmt(t[reference].median, 's')}",
                    why_missed=notes.projection_case(t[side].median, t["trace"].median),
                )
            )
    rows.append(
        Row(
            f"{case}, objective camera, default (beauty: run's primal), vs backward at "
            f"{s.view_spp} spp",
            t["objective"].ratio_to(t["adjoint"]),
            "x",
            Goal("<=", 1 / 20, "1/20"),
            f"view {fmt(t['objective'].median, 's')} vs backward {adjoint}",
        )
    )
    rows.append(
        Row(
            f"{case}, visibility only (beauty 0), vs the visibility trace alone",
            t["no_beauty"].ratio_to(t["trace"]),
            "x",
            Goal("<=", 1.5),
            f"view {fmt(t['no_beauty'].median, 's')} vs trace {fmt(t['trace'].median, 's')}",
            why_missed=notes.projection_case(t["no_beauty"].median, t["trace"].median),
        )
    )
    rows.append(
        Row(
            f"{case}, visibility trace alone, vs backward at {s.view_spp} spp",
            t["trace"].ratio_to(t["adjoint"]),
            "x",
            None,
            f"trace {fmt(t['trace'].median, 's')} vs backward {adjoint}",
        )
    )
    return rows


def _make_buffer(job: Path) -> Path:
    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.run import run_job
    from sensaov_cli.progress import Progress

    spec = load_job(job)
    run_job(spec, allow_python=False, progress=Progress(quiet=True))
    return spec.output / "buffer.npz"


def _view(
    job: Path, buffer_path: Path, beauty_spp: int, camera: str = CAMERA
) -> Callable[[], float]:
    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.project import project_job
    from sensaov_cli.progress import Progress

    spec = load_job(job)

    def measure() -> float:
        progress = Progress(quiet=True)
        (view,) = project_job(
            spec,
            buffer_path=buffer_path,
            cameras=(camera,),
            beauty_spp=beauty_spp,
            progress=progress,
        )
        # ``seconds`` is the view stage alone; the camera's trace, painting and display scales
        # run in the shared visibility stage before it (one camera here: all of it is this view's).
        return float(view.seconds) + progress.timings["visibility_s"]

    return measure


def _trace(job: Path, vis_spp: int) -> Callable[[], float]:
    """``visibility.trace`` alone on the inspection camera, the pass a view is built on."""
    from sensaov_cli.job.load import load_job
    from sensaov_cli.render.loading import load_job_scene
    from sensaov_cli.render.visibility import trace

    spec = load_job(job)

    loaded = load_job_scene(spec, spec.inspection_cameras)
    sensor = loaded.inspection_sensors[CAMERA]
    return lambda: synced(
        lambda: trace(loaded.mi, loaded.scene, sensor, loaded.objects, vis_spp, seed=0)
    )[0]
