"""SIGTERM, SIGINT and SIGKILL at every point of ``run`` and ``project``: nothing is lost.

Each case starts from a folder holding the outputs of an earlier run (the "previous version"),
sends a signal at one point (the interpreter's imports, the scene load and Mitsuba import, the
primal render, a backward pass, a view, the writer of one output, the renames) through
``signal_driver.py``, and checks: every output present is its previous version or a complete,
loadable new one; after SIGTERM/SIGINT no temporary is left, the exit code is 143/130 and the
one line on stderr names exactly the outputs that were replaced; the process ended within
TERM_BOUND_S of the signal (measured on this machine's tiny scene: 0.1-0.5 s; the bound leaves
room for a loaded CI machine). The scenes are 16x16 at 4 spp, so the whole module takes ~40 s.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import EXIT_HANGUP, EXIT_INTERRUPTED, EXIT_TERMINATED
from sensaov_cli.outputs.atomic import TEMPORARY_SUFFIX
from sensaov_cli.outputs.exr import read_exr

from .conftest import ROOT, sensaov, write_job

DRIVER = Path(__file__).with_name("signal_driver.py")
TERM_BOUND_S = 3.0
RENDER = {"spp": 4, "max_depth": 3, "seed": 0, "resolution": [16, 16]}


@pytest.fixture(scope="module")
def previous(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The outputs of one complete ``run`` and ``project --png``: the previous version."""
    job = write_job(tmp_path_factory.mktemp("previous"), render=RENDER)
    for command in (["run", "-q"], ["project", "-q", "--png", "--beauty-spp", "1"]):
        result = sensaov(*command, str(job))
        assert result.returncode == 0, result.stderr
    return job.parent / "out"


def snapshot(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def loadable(path: Path) -> None:
    """Raise unless ``path`` is a complete file of its kind."""
    if path.suffix == ".npz":
        read_buffer(path)
    elif path.suffix == ".exr":
        read_exr(path)
    elif path.suffix == ".png":
        import OpenImageIO as oiio

        image = oiio.ImageInput.open(str(path))
        assert image is not None, oiio.geterror()
        pixels = image.read_image()
        image.close()
        assert pixels is not None and np.asarray(pixels).size > 0
    else:
        raise AssertionError(f"unexpected output {path}")


def interrupted(
    tmp_path: Path, previous: Path, command: list[str], point: str, sig: str, delay: float = 0.0
) -> tuple[subprocess.CompletedProcess[str], dict[str, bytes], float | None]:
    job = write_job(tmp_path, render=RENDER)
    shutil.copytree(previous, tmp_path / "out")
    stamp = tmp_path / "stamp"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    args = [sys.executable, str(DRIVER), point, sig, str(delay), str(stamp), *command, str(job)]
    result = subprocess.run(args, capture_output=True, text=True, env=env, timeout=300)
    ended = time.monotonic()
    sent = stamp.read_text() if stamp.exists() else ""
    return result, snapshot(tmp_path / "out"), (ended - float(sent)) if sent else None


def check_outcome(
    result: subprocess.CompletedProcess[str],
    before: dict[str, bytes],
    after: dict[str, bytes],
    sig: str,
    delay_s: float | None,
) -> set[str]:
    """The invariants every case shares; returns the outputs that were replaced (as the message
    names them; after SIGKILL, those whose bytes changed)."""
    out = Path(result.args[-1]).parent / "out"
    temporaries = [name for name in after if name.endswith(TEMPORARY_SUFFIX)]
    changed = {n for n, data in after.items() if n not in temporaries and before.get(n) != data}
    assert set(before) <= set(after), "an output vanished"
    for name in changed:
        loadable(out / name)
    if sig == "KILL":
        assert result.returncode == -signal.SIGKILL
        return changed
    assert not temporaries, temporaries
    code = {"TERM": EXIT_TERMINATED, "INT": EXIT_INTERRUPTED, "HUP": EXIT_HANGUP}[sig]
    assert result.returncode == code, result.stderr
    assert "Traceback" not in result.stderr
    line = result.stderr.strip()
    assert "\n" not in line, result.stderr
    assert line.startswith(f"sensaov: error: stopped by SIG{sig}")
    replaced: set[str] = set()
    if "; replaced: " in line:  # a re-rendered PNG may come out byte for byte the same
        listed = line.split("; replaced: ")[1].split("; no other output")[0].split(", ")
        replaced = {str(Path(name).relative_to(out)) for name in listed}
    else:
        assert line.endswith("no output was replaced"), line
    assert changed <= replaced, (changed, line)
    for name in replaced:
        loadable(out / name)
    assert delay_s is not None and delay_s < TERM_BOUND_S, delay_s
    return replaced


RUN_CASES = [
    # point, signal, delay after the stage began, what must have been replaced
    ("stage:load_s", "TERM", 0.0, set()),  # before Mitsuba is imported
    ("stage:load_s", "TERM", 0.1, set()),  # during Mitsuba's import or the scene load
    ("stage:primal_s", "TERM", 0.005, set()),
    ("stage:backward_", "TERM", 0.005, set()),
    ("stage:backward_", "INT", 0.005, set()),
    ("stage:backward_", "HUP", 0.005, set()),  # a closed terminal: a stop like the others
    ("rename", "HUP", 0.0, {"buffer.npz", "primal.exr"}),
    ("write:1", "TERM", 0.0, set()),  # the buffer half written
    ("write:2", "TERM", 0.0, set()),  # the buffer complete, the primal EXR half written
    ("rename", "TERM", 0.0, {"buffer.npz", "primal.exr"}),  # both renamed together
    ("stage:primal_s", "KILL", 0.005, set()),
    ("write:2", "KILL", 0.0, set()),
    ("rename", "KILL", 0.0, {"buffer.npz"}),  # killed between the two renames
]


@pytest.mark.parametrize(("point", "sig", "delay", "expected"), RUN_CASES)
def test_run_stopped(
    tmp_path: Path, previous: Path, point: str, sig: str, delay: float, expected: set[str]
) -> None:
    result, after, delay_s = interrupted(tmp_path, previous, ["run", "-q"], point, sig, delay)
    replaced = check_outcome(result, snapshot(previous), after, sig, delay_s)
    if sig != "KILL" or point != "rename":
        assert replaced == expected, result.stderr
    else:  # SIGKILL lands before the first rename or between the two: either is whole
        assert replaced <= {"buffer.npz", "primal.exr"}


PROJECT_CASES = [
    ("stage:load_s", "TERM", 0.05, set()),
    ("stage:view_", "TERM", 0.005, set()),
    ("stage:view_", "HUP", 0.005, set()),
    ("write:1", "TERM", 0.0, set()),  # the camera's EXR half written
    ("write:3", "TERM", 0.0, {"objective.exr", "previews/objective/mean_luma.objects.png"}),
    ("rename", "TERM", 0.0, {"objective.exr"}),
    ("write:3", "KILL", 0.0, {"objective.exr", "previews/objective/mean_luma.objects.png"}),
]


@pytest.mark.parametrize(("point", "sig", "delay", "expected"), PROJECT_CASES)
def test_project_stopped(
    tmp_path: Path, previous: Path, point: str, sig: str, delay: float, expected: set[str]
) -> None:
    command = ["project", "-q", "--png", "--beauty-spp", "1"]
    result, after, delay_s = interrupted(tmp_path, previous, command, point, sig, delay)
    replaced = check_outcome(result, snapshot(previous), after, sig, delay_s)
    if sig == "KILL":  # no message: the bytes tell, and a re-drawn PNG may be the same bytes
        assert "objective.exr" in replaced and replaced <= expected
    else:
        assert replaced == expected, result.stderr


@pytest.mark.parametrize("sig", ["TERM", "HUP"])
def test_a_stop_just_after_the_report_was_written_still_says_so(
    tmp_path: Path, previous: Path, sig: str
) -> None:
    """The report is whole and in place; the process still ends 143/129 with its one line,
    which names the report (it used to die without a word)."""
    result, after, delay_s = interrupted(tmp_path, previous, ["report"], "written", sig)
    code = {"TERM": EXIT_TERMINATED, "HUP": EXIT_HANGUP}[sig]
    report = tmp_path / "out" / "report.html"
    assert result.returncode == code, result.stderr
    line = result.stderr.strip()
    assert "\n" not in line and line.startswith(f"sensaov: error: stopped by SIG{sig}"), line
    assert line.endswith(f"; replaced: {report}; no other output was touched"), line
    assert after["report.html"].rstrip().endswith(b"</html>")
    assert not [name for name in after if name.endswith(TEMPORARY_SUFFIX)]
    assert delay_s is not None and delay_s < TERM_BOUND_S


@pytest.mark.parametrize("delay", [0.03, 0.08, 0.2])
def test_sigterm_while_the_interpreter_imports(
    tmp_path: Path, previous: Path, delay: float
) -> None:
    """Before sensaov's first line the default action ends the process (the shell says 143);
    from then on the signal is recorded and the command exits 143 with its one line."""
    job = write_job(tmp_path, render=RENDER)
    shutil.copytree(previous, tmp_path / "out")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    process = subprocess.Popen(
        [sys.executable, "-m", "sensaov_cli", "run", "-q", str(job)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    time.sleep(delay)
    process.send_signal(signal.SIGTERM)
    sent = time.monotonic()
    _, stderr = process.communicate(timeout=120)
    assert time.monotonic() - sent < TERM_BOUND_S
    assert process.returncode in (EXIT_TERMINATED, -signal.SIGTERM), stderr
    assert "Traceback" not in stderr and "terminate" not in stderr
    assert stderr in ("", "sensaov: error: stopped by SIGTERM; no output was replaced\n")
    assert snapshot(tmp_path / "out") == snapshot(previous)


def test_sigterm_during_a_long_backward_pass_ends_within_one_sub_pass(tmp_path: Path) -> None:
    """A 256² x 256 spp backward pass (2^24 samples) takes ~12 s on 2 cores; split into
    sub-passes of 2^19 samples it stops within one of them: measured 0.3-0.4 s after SIGTERM
    (11-13 s with the split disabled, docs/exit-codes.md). The bound leaves room for a slow CI."""
    render = {"spp": 256, "max_depth": 6, "seed": 0, "resolution": [256, 256]}
    job = write_job(tmp_path, render=render)
    process = subprocess.Popen(
        [sys.executable, "-m", "sensaov_cli", "run", str(job), "--progress", "plain"],
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stderr is not None
    seen = ""
    while "backward pass" not in seen:
        char = process.stderr.read(1)
        assert char, seen  # the run ended before its backward pass
        seen += char
    time.sleep(0.5)
    sent = time.perf_counter()
    process.send_signal(signal.SIGTERM)
    rest = process.stderr.read()
    process.wait(timeout=60)
    waited = time.perf_counter() - sent
    assert process.returncode == EXIT_TERMINATED, rest
    assert waited < TERM_BOUND_S, f"{waited:.2f} s from SIGTERM to exit"
    assert not (job.parent / "out").exists() or not list((job.parent / "out").iterdir())


def test_sigterm_at_random_points_of_a_large_view(tmp_path: Path) -> None:
    """``project`` on a 512² camera at 64 visibility spp (16.7 M samples: ~2 s of tracing in
    one launch before the pass was split), SIGTERM at 10 random points between the start of
    the scene load and the end of the view: exit 143 within 1 s of the signal each time."""
    job = write_job(tmp_path, render={**RENDER, "spp": 2}, inspection_cameras=[LARGE_CAMERA])
    assert sensaov("run", "-q", str(job)).returncode == 0
    for _ in range(2):  # the window of a warm run (kernels compiled), as every run below is
        process = _project_loading(job)
        started = time.perf_counter()
        _, whole = process.communicate(timeout=120)
        assert process.returncode == 0, whole
        window = time.perf_counter() - started  # the load, both views and the writes
    waits, codes = [], []
    for delay in np.random.default_rng(21).uniform(0.0, 0.8 * window, 10):
        for _ in range(8):
            process = _project_loading(job)
            time.sleep(delay)
            sent = time.perf_counter()
            process.send_signal(signal.SIGTERM)
            _, rest = process.communicate(timeout=60)
            if process.returncode != 0:
                break
            delay /= 2  # this run ended before the signal came (runs vary): come sooner
        waits.append(time.perf_counter() - sent)
        codes.append(process.returncode)
        last = rest.strip().splitlines()[-1]
        assert last.startswith("sensaov: error: stopped by SIGTERM"), (process.returncode, rest)
    print(f"window {window:.2f} s; SIGTERM to exit: {', '.join(f'{w:.2f}' for w in waits)} s")
    assert codes == [EXIT_TERMINATED] * 10, codes
    assert max(waits) < LARGE_VIEW_BOUND_S, waits


def _project_loading(job: Path) -> subprocess.Popen[str]:
    """``project`` started and past the moment its scene load began (read from its stderr)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "sensaov_cli", "project", str(job)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert process.stderr is not None
    seen = ""
    while "loading" not in seen:
        char = process.stderr.read(1)
        assert char, seen  # it ended before the scene load
        seen += char
    return process


LARGE_VIEW_BOUND_S = 1.0  # the acceptance bound
LARGE_CAMERA = {
    "name": "big",
    "look_at": {"origin": [0, 0, 3.9], "target": [0, 0, 0], "up": [0, 1, 0]},
    "resolution": [512, 512],
    "vis_spp": 64,
}


@pytest.mark.parametrize(
    ("command", "point", "job", "bound"),
    [
        (  # 128² x 128 spp: four forward sub-passes of 2^19 samples
            ["run", "-q"],
            "stage:forward_",
            {
                "render": {**RENDER, "spp": 128, "resolution": [128, 128]},
                "forward": [{"name": "light", "object": "light"}],
            },
            TERM_BOUND_S,  # a forward sub-pass of 2^19 samples takes ~0.9 s on 2 cores
        ),
        (  # the visibility pass with UVs that texel fields are painted through (project traces
            # every camera in its shared stage, for the display scales, before any view)
            ["project", "-q", "--beauty-spp", "1"],
            "stage:visibility",
            {
                "inspection_cameras": [LARGE_CAMERA],
                "channels": [{"name": "t", "kind": "texel"}],
            },
            LARGE_VIEW_BOUND_S,
        ),
    ],
    ids=["forward", "texel"],
)
def test_sigterm_in_a_forward_or_texel_pass_ends_within_one_chunk(
    tmp_path: Path, command: list[str], point: str, job: dict[str, object], bound: float
) -> None:
    """The stop lands 0.3 s into the pass and is acted on when the running launch returns:
    a visibility chunk (tens of ms) or a forward sub-pass (measured 0.69 s after SIGTERM with
    the machine shared, the sub-pass itself ~0.9 s: 1 s is not guaranteed there, 3 s is)."""
    path = write_job(tmp_path, **{"render": RENDER, **job})
    if command[0] == "project":  # its buffer first
        assert sensaov("run", "-q", str(path)).returncode == 0
    stamp = tmp_path / "stamp"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    args = [sys.executable, str(DRIVER), point, "TERM", "0.3", str(stamp), *command, str(path)]
    result = subprocess.run(args, capture_output=True, text=True, env=env, timeout=300)
    waited = time.monotonic() - float(stamp.read_text())
    assert result.returncode == EXIT_TERMINATED, result.stderr
    assert result.stderr.startswith("sensaov: error: stopped by SIGTERM"), result.stderr
    print(f"{point}: {waited:.2f} s from SIGTERM to exit")
    assert waited < bound, f"{waited:.2f} s from SIGTERM to exit"
