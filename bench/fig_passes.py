"""Figures 2, 3 and 8: single passes timed in-process with the library.

Each pass is timed with ``dr.sync_thread()`` on both ends; every comparison gets one untimed
warm-up round first (Dr.Jit bakes resolution and spp into its kernels, so each configuration
compiles once, then hits the kernel cache). Backward passes run on all threads
(``deterministic: false``), as the primal does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench import notes
from bench.jobs import SCENES, Workspace
from bench.results import Figure, Goal, Row, fmt
from bench.settings import Settings
from bench.timing import Stats, interleave, synced

PRIMAL_SEED, GRAD_SEED = 0, 1
LUMA = (0.2126, 0.7152, 0.0722)
Log = Callable[[str], None]


@dataclass
class Passes:
    """A loaded scene, its objectives and a fixed dM/dI, ready to time passes on."""

    loaded: Any
    objectives: list[Any]
    adjoint: Any  # dM/dI of the first objective at the primal
    spp: int

    @staticmethod
    def load(job: Path) -> Passes:
        from sensaov_cli.job.load import load_job
        from sensaov_cli.render.adjoint import enable_gradients, render_primal
        from sensaov_cli.render.loading import load_job_scene
        from sensaov_cli.render.objectives import build_objectives, value_and_adjoint

        spec = load_job(job)
        loaded = load_job_scene(spec)
        width, height = loaded.resolution
        objectives = build_objectives(loaded.mi, spec.objectives, (height, width), False)
        enable_gradients(loaded)
        image = render_primal(loaded, spec.render.spp, PRIMAL_SEED)
        _, adjoint = value_and_adjoint(loaded.mi, objectives[0], image)
        return Passes(loaded, objectives, adjoint, spec.render.spp)

    def primal(self) -> float:
        from sensaov_cli.render.adjoint import render_primal

        return synced(lambda: render_primal(self.loaded, self.spp, PRIMAL_SEED))[0]

    def backward(self) -> float:
        from sensaov_cli.render.adjoint import backward

        return synced(lambda: backward(self.loaded, self.adjoint, self.spp, GRAD_SEED))[0]

    def mitsuba_backward(self) -> float:
        """The same pass with no sensaov code: ``render_backward``, then read each gradient."""
        import drjit as dr

        from sensaov_cli.render.adjoint import pass_leaves

        scene = self.loaded
        # Untimed: every selected parameter gradient-enabled in the scene. These are the leaves
        # sensaov's own backward (interleaved with this one) keeps for its next pass, so neither
        # side pays a `params.update()` in its timed part (a run pays one, as the script does).
        pass_leaves(scene, {info.key for info in scene.selected})

        def run() -> None:
            scene.integrator.render_backward(
                scene.scene,
                scene.params,
                grad_in=self.adjoint,
                sensor=scene.sensor,
                seed=GRAD_SEED,
                spp=self.spp,
            )
            for info in scene.selected:
                np.array(dr.grad(scene.params[info.key]))
                dr.clear_grad(scene.params[info.key])

        return synced(run)[0]

    def components(self, textures: bool = True) -> int:
        return sum(
            int(np.prod(info.shape))
            for info in self.loaded.selected
            if textures or not info.is_texture
        )


@dataclass(frozen=True)
class PassTimes:
    """Primal and backward times of one configuration, measured in the same rounds."""

    case: str
    primal: Stats
    backward: Stats
    components: int
    components_no_textures: int


def adjoint_cost(ws: Workspace, s: Settings, log: Log) -> tuple[Figure, list[PassTimes]]:
    figure = Figure(
        2,
        "Adjoint cost: one backward pass / one primal render",
        "≤ 2.2× (prb replays the path: about 2×)",
        f"In-process: `render_primal` vs `backward` (prb `render_backward` plus reading every "
        f"gradient back to numpy) at the same resolution and {s.spp} spp, and the same "
        "backward pass written with Mitsuba alone; the three interleaved, `dr.sync_thread()` "
        "around each, all threads. Reference: Mitsuba's diffuse-only `cornell_box()` under "
        "prb, measured the same way.",
    )
    measured, rows = [], []
    for scene in SCENES:
        for res in s.resolutions:
            passes = Passes.load(
                ws.job(f"cost_{scene}_{res}", SCENES[scene], resolution=res, spp=s.spp)
            )
            t = interleave(
                {
                    "primal": passes.primal,
                    "backward": passes.backward,
                    "mitsuba": passes.mitsuba_backward,
                },
                s.rounds,
            )
            case = f"{scene} {res}²"
            measured.append(
                PassTimes(
                    case, t["primal"], t["backward"], passes.components(), passes.components(False)
                )
            )
            rows += _cost_rows(case, t, len(passes.loaded.selected))
            log(f"figure 2: {case} done")
    reference = _cornell_reference(s)
    figure.rows += [_with_note(rows, i) for i in range(len(rows))] + [reference]
    figure.why_missed = notes.adjoint(reference.stats.median)
    log("figure 2: reference done")
    return figure, measured


def _cost_rows(case: str, t: dict[str, Stats], params: int) -> list[Row]:
    return [
        Row(
            case,
            t["backward"].ratio_to(t["primal"]),
            "x",
            Goal("<=", 2.2),
            f"primal {fmt(t['primal'].median, 's')}, backward {fmt(t['backward'].median, 's')} "
            f"({params} parameters)",
        ),
        Row(
            f"{case}, Mitsuba alone",
            t["mitsuba"].ratio_to(t["primal"]),
            "x",
            None,
            f"backward {fmt(t['mitsuba'].median, 's')}",
        ),
        Row(
            f"{case}, sensaov's backward / Mitsuba's",
            t["backward"].ratio_to(t["mitsuba"]),
            "x",
            Goal("<=", 1.03),
            "per round, the same scene, seed and spp (issue 23)",
            why_missed=f"sensaov {fmt(t['backward'].median, 's')} vs Mitsuba "
            f"{fmt(t['mitsuba'].median, 's')}",
        ),
    ]


def _with_note(rows: list[Row], index: int) -> Row:
    """The goal row gets the note, with the Mitsuba-alone ratio of the row after it."""
    row = rows[index]
    if row.goal is None or row.why_missed:
        return row
    alone = rows[index + 1].stats.median
    note = notes.adjoint_case(row.stats.median, alone)
    return Row(row.case, row.stats, row.unit, row.goal, row.detail, why_missed=note)


def _cornell_reference(s: Settings) -> Row:
    """backward / primal on ``mi.cornell_box()`` (diffuse only) with Mitsuba alone."""
    import drjit as dr
    import mitsuba as mi

    res = s.resolutions[-1]
    spec = mi.cornell_box()
    spec["integrator"] = {"type": "prb", "max_depth": 6}
    spec["sensor"]["film"].update(width=res, height=res)
    scene = mi.load_dict(spec, optimize=False)
    params = mi.traverse(scene)
    keys = [k for k in params.keys() if k.endswith(("reflectance.value", "radiance.value"))]
    for key in keys:
        dr.enable_grad(params[key])
    params.update()
    integrator = scene.integrator()

    def primal() -> float:
        with dr.suspend_grad():
            return synced(lambda: np.array(integrator.render(scene, seed=PRIMAL_SEED, spp=s.spp)))[
                0
            ]

    channels = np.array(integrator.render(scene, seed=PRIMAL_SEED, spp=1)).shape[2]
    weights = np.zeros((res, res, channels), np.float32)
    weights[..., :3] = np.array(LUMA, np.float32) / (res * res)
    grad_in = mi.TensorXf(weights)

    def backward() -> float:
        def run() -> None:
            integrator.render_backward(scene, params, grad_in=grad_in, seed=GRAD_SEED, spp=s.spp)
            for key in keys:
                np.array(dr.grad(params[key]))
                dr.clear_grad(params[key])

        return synced(run)[0]

    t = interleave({"primal": primal, "backward": backward}, s.rounds)
    return Row(
        f"reference: cornell_box() {res}², diffuse only, Mitsuba alone",
        t["backward"].ratio_to(t["primal"]),
        "x",
        None,
        f"primal {fmt(t['primal'].median, 's')}, backward "
        f"{fmt(t['backward'].median, 's')} ({len(keys)} parameters)",
    )


def texture_independence(ws: Workspace, s: Settings, log: Log) -> tuple[Figure, list[PassTimes]]:
    figure = Figure(
        3,
        f"Parameter-count independence: backward with a {s.texture}² texture selected / excluded",
        "≤ 1.3×",
        f"A copy of scenes/cbox (in a scratch directory) whose checker wall carries a "
        f"{s.texture}² 8-bit RGB PNG; the same scene loaded twice, once with the texture in "
        "the buffer and once with it in `parameters.exclude`. Backward passes interleaved, "
        f"{s.spp} spp, all threads. The primal of the textured scene is timed in the same "
        "rounds for figure 8.",
    )
    figure.why_missed = notes.TEXTURE
    scene = ws.textured_cbox(s.texture)
    measured = []
    for res in s.resolutions:
        with_tex = Passes.load(ws.job(f"tex_{res}", scene, resolution=res, spp=s.spp))
        textures = tuple(i.key for i in with_tex.loaded.selected if i.is_texture)
        without = Passes.load(
            ws.job(f"notex_{res}", scene, resolution=res, spp=s.spp, exclude=textures)
        )
        t = interleave(
            {"primal": with_tex.primal, "with": with_tex.backward, "without": without.backward},
            s.rounds,
        )
        case = f"cbox+{s.texture}² texture {res}²"
        figure.rows.append(_texture_row(case, t["with"], t["without"], with_tex, without))
        measured.append(
            PassTimes(
                case, t["primal"], t["with"], with_tex.components(), with_tex.components(False)
            )
        )
        log(f"figure 3: {res}² done")
    return figure, measured


def _texture_row(case: str, with_: Stats, without: Stats, a: Passes, b: Passes) -> Row:
    delta = Stats.of([x - y for x, y in zip(with_.values, without.values, strict=True)])
    return Row(
        case,
        with_.ratio_to(without),
        "x",
        Goal("<=", 1.3),
        f"{a.components():,} vs {b.components():,} scalar components; backward "
        f"{fmt(with_.median, 's')} vs {fmt(without.median, 's')}",
        why_missed=notes.texture_case(delta.median),
    )


def finite_differences(measured: list[PassTimes]) -> Figure:
    figure = Figure(
        8,
        "Versus finite differences: central differences over every component / one adjoint",
        "report the speed-up and the parameter count (no goal)",
        "**Extrapolated, not run:** central differences need 2 primal renders per scalar "
        "component, so their time is 2 × components × the primal time measured in figures 2 "
        "and 3; the adjoint is one primal plus one backward pass, measured in the same rounds. "
        "Per-round speed-ups, so min/max carry the timing noise.",
    )
    for times in measured:
        adjoint = Stats.of(
            [p + b for p, b in zip(times.primal.values, times.backward.values, strict=True)]
        )
        for label, count in (
            ("all parameters", times.components),
            ("without textures", times.components_no_textures),
        ):
            if label == "without textures" and count == times.components:
                continue
            fd = times.primal.scaled(2 * count)
            figure.rows.append(
                Row(
                    f"{times.case}, {label} ({count:,} components)",
                    fd.ratio_to(adjoint),
                    "speedup",
                    None,
                    f"FD ≈ {fmt(fd.median, 's')} vs adjoint {fmt(adjoint.median, 's')}",
                )
            )
    return figure
