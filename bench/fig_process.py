"""Figures 1, 6 and 7: whole processes, timed from spawn to exit, peak RSS from ``wait4``."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from bench import notes
from bench.jobs import EXTRA_OBJECTIVES, MEAN_LUMA, SCENES, PlainInputs, Workspace
from bench.results import Figure, Goal, Row, fmt
from bench.settings import Settings
from bench.timing import ChildRun, Stats, interleave, run_child

BIN = Path(sys.executable).parent
SENSAOV = str(BIN / "sensaov")
PLAIN = str(Path(__file__).with_name("plain_mitsuba.py"))
MB = 1e6
Log = Callable[[str], None]


def _sensaov_run(job: Path, record: list[ChildRun] | None = None) -> Callable[[], float]:
    def measure() -> float:
        child = run_child([SENSAOV, "run", str(job), "-q", "--json"])
        if record is not None:
            record.append(child)
        return child.seconds

    return measure


def _plain(
    inputs: PlainInputs,
    spp: int,
    variant: str,
    primal_only: bool = False,
    record: list[ChildRun] | None = None,
) -> Callable[[], float]:
    command = [
        sys.executable,
        PLAIN,
        str(inputs.xml),
        "--resolver",
        str(inputs.resolver),
        "--sensor",
        inputs.sensor,
        "--keys",
        str(inputs.keys),
        "--spp",
        str(spp),
        "--variant",
        variant,
    ]
    command += ["--primal-only"] if primal_only else []

    def measure() -> float:
        child = run_child(command)
        if record is not None:
            record.append(child)
        return child.seconds

    return measure


def pipeline_overhead(ws: Workspace, s: Settings, variant: str, log: Log) -> Figure:
    figure = Figure(
        1,
        "Pipeline overhead: `sensaov run` / a hand-written Mitsuba script",
        "≤ 1.10×; ≤ 1.05× at the larger size (issue 23)",
        "Whole-process wall time, start-up included: `sensaov run job.yaml -q --json` (one "
        "objective, mean luminance; writes buffer.npz and primal.exr) against "
        "`bench/plain_mitsuba.py` (load the same scene text, one primal, one `render_backward` "
        f"with dM/dI of the mean luminance, gradients to numpy), same {s.spp} spp and "
        "parameters. sensaov runs with `deterministic: false` (all threads, as the script, and "
        "the default since issue 12); `deterministic: true` is its own line. The three are "
        "interleaved after one warm-up round.",
    )
    for scene in SCENES:
        for res in s.resolutions:
            free = ws.job(f"run_{scene}_{res}", SCENES[scene], resolution=res, spp=s.spp)
            det = ws.job(
                f"rundet_{scene}_{res}",
                SCENES[scene],
                resolution=res,
                spp=s.spp,
                deterministic=True,
            )
            inputs = ws.plain_inputs(free)
            t = interleave(
                {
                    "sensaov": _sensaov_run(free),
                    "plain": _plain(inputs, s.spp, variant),
                    "deterministic": _sensaov_run(det),
                },
                s.process_rounds,
            )
            case = f"{scene} {res}²"
            goal = 1.05 if res == max(s.resolutions) else 1.10  # issue 23: 1.05× at the larger
            figure.rows += _overhead_rows(case, t, inputs.count, goal)
            log(f"figure 1: {case} done")
    figure.why_missed = notes.OVERHEAD
    figure.remarks.append(notes.DETERMINISTIC)
    return figure


def _overhead_rows(case: str, t: dict[str, Stats], params: int, goal: float) -> list[Row]:
    plain = t["plain"].median
    delta = Stats.of([a - b for a, b in zip(t["sensaov"].values, t["plain"].values, strict=True)])
    return [
        Row(
            f"{case}, deterministic: false",
            t["sensaov"].ratio_to(t["plain"]),
            "x",
            Goal("<=", goal),
            f"sensaov {fmt(t['sensaov'].median, 's')} vs script {fmt(plain, 's')}, "
            f"Δ {delta.median:+.2f} s ({params} parameters)",
            why_missed=notes.overhead_case(delta.median, plain),
        ),
        Row(
            f"{case}, deterministic: true",
            t["deterministic"].ratio_to(t["plain"]),
            "x",
            None,
            f"sensaov {fmt(t['deterministic'].median, 's')} vs script {fmt(plain, 's')}; "
            f"{t['deterministic'].ratio_to(t['sensaov']).median:.2f}× the deterministic: false "
            "run",
        ),
    ]


def memory(ws: Workspace, s: Settings, variant: str, log: Log) -> Figure:
    lo, hi = s.memory_spp
    res = s.memory_resolution
    figure = Figure(
        6,
        "Memory: peak RSS of `sensaov run`",
        f"{hi} spp / {lo} spp ≤ 1.1× (flat in spp); run / primal alone ≤ 1.5×",
        f"Peak resident set of each child process from `os.wait4` (its own `ru_maxrss`). "
        f'cbox at {res}², one objective, `deterministic: false`. "Primal alone" is '
        f"`bench/plain_mitsuba.py --primal-only` on the same scene text at {lo} spp "
        "(imports Mitsuba, loads the scene, renders the primal, exits); the script's full run "
        "(primal + backward) is shown for reference. Interleaved after one warm-up round.",
    )
    runs: dict[str, list[ChildRun]] = {"lo": [], "hi": [], "primal": [], "plain": []}
    job_lo = ws.job(f"mem_{lo}", SCENES["cbox"], resolution=res, spp=lo)
    job_hi = ws.job(f"mem_{hi}", SCENES["cbox"], resolution=res, spp=hi)
    inputs = ws.plain_inputs(job_lo)
    interleave(
        {
            "lo": _sensaov_run(job_lo, runs["lo"]),
            "hi": _sensaov_run(job_hi, runs["hi"]),
            "primal": _plain(inputs, lo, variant, True, runs["primal"]),
            "plain": _plain(inputs, lo, variant, False, runs["plain"]),
        },
        s.process_rounds,
    )
    rss = {
        k: Stats.of([c.max_rss_bytes / MB for c in v[-s.process_rounds :]]) for k, v in runs.items()
    }
    figure.rows += _memory_rows(rss, lo, hi)
    log("figure 6: done")
    return figure


def _memory_rows(rss: dict[str, Stats], lo: int, hi: int) -> list[Row]:
    def mb(key: str) -> str:
        return fmt(rss[key].median, "MB")

    extra = rss["lo"].median - rss["primal"].median
    backward = rss["plain"].median - rss["primal"].median
    return [
        Row(
            f"run {hi} spp / run {lo} spp",
            rss["hi"].ratio_to(rss["lo"]),
            "x",
            Goal("<=", 1.1),
            f"{mb('hi')} vs {mb('lo')}",
            why_missed=notes.memory_spp(rss["hi"].median, rss["lo"].median),
        ),
        Row(
            f"run {lo} spp / primal alone",
            rss["lo"].ratio_to(rss["primal"]),
            "x",
            Goal("<=", 1.5),
            f"{mb('lo')} vs {mb('primal')}",
            why_missed=notes.memory_primal(extra, backward),
        ),
        Row(
            f"script primal + backward / primal alone ({lo} spp)",
            rss["plain"].ratio_to(rss["primal"]),
            "x",
            None,
            f"{mb('plain')} vs {mb('primal')}",
        ),
    ]


def startup(ws: Workspace, s: Settings, log: Log) -> Figure:
    figure = Figure(
        7,
        "Start-up: whole-process wall time",
        "`sensaov --help` ≤ 0.3 s; `sensaov rank` (the summary, and one cut with `--by key`) "
        f"on a buffer with a {s.texture}² texture ≤ 0.5 s; none imports Mitsuba or Dr.Jit",
        f"Wall time from spawn to exit of the installed `sensaov` script. The buffer comes "
        f"from `sensaov run` on the textured cbox copy of figure 3 (two objectives, so three "
        f"{s.texture}²×3 arrays). Imports checked with `python -X importtime -m sensaov_cli`. "
        "`python -c pass` is timed in the same rounds as the floor.",
    )
    figure.why_missed = notes.STARTUP
    buffer = _textured_buffer(ws, s.texture)
    commands = {
        "help": [SENSAOV, "--help"],
        "rank": [SENSAOV, "rank", str(buffer)],
        "rank_by_key": [SENSAOV, "rank", str(buffer), "--by", "key", "--top", "20"],
        "python": [sys.executable, "-c", "pass"],
    }
    t = interleave({k: _wall(c) for k, c in commands.items()}, s.startup_rounds)
    size = fmt(buffer.stat().st_size / MB, "MB")
    floor = fmt(t["python"].median, "s")
    for key, limit, label in (
        ("help", 0.3, "sensaov --help"),
        ("rank", 0.5, f"sensaov rank ({size} buffer)"),
        ("rank_by_key", 0.5, f"sensaov rank --by key --top 20 ({size} buffer)"),
    ):
        heavy = _heavy_imports(commands[key][1:])
        figure.rows.append(
            Row(
                label,
                t[key],
                "s",
                Goal("<=", limit),
                f"imports {', '.join(heavy) or 'no mitsuba/drjit'}; python floor {floor}",
                check_ok=not heavy,
            )
        )
    log("figure 7: done")
    return figure


def _textured_buffer(ws: Workspace, texture: int) -> Path:
    """A real buffer holding a ``texture``² texture gradient, from a small `sensaov run`."""
    job = ws.job(
        "rank_tex",
        ws.textured_cbox(texture),
        resolution=64,
        spp=4,
        objectives=[MEAN_LUMA, EXTRA_OBJECTIVES[0]],
    )
    run_child([SENSAOV, "run", str(job), "-q", "--json"])
    return ws.root / "out" / "rank_tex" / "buffer.npz"


def _wall(command: list[str]) -> Callable[[], float]:
    return lambda: run_child(command).seconds


def _heavy_imports(arguments: list[str]) -> list[str]:
    import subprocess

    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "sensaov_cli", *arguments],
        capture_output=True,
        text=True,
        check=True,
    )
    names = {line.rsplit("|", 1)[-1].strip().split(".")[0] for line in done.stderr.splitlines()}
    return sorted(names & {"mitsuba", "drjit"})
