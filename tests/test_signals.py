"""SIGTERM, SIGINT and SIGKILL at every point of ``run`` and ``project``: nothing is lost.

Each case starts from a folder holding the outputs of an earlier run (the "previous version"),
sends a signal at one point (the interpreter's imports, the scene load and Mitsuba import, the
primal render, a backward pass, a view, the writer of one output, the renames) through
``signal_driver.py``, and checks: every output present is its previous version or a complete,
loadable new one; after SIGTERM/SIGINT no temporary is left, the exit code is 143/130 and the
one line on stderr names exactly the outputs that were replaced; no chunk of work (sub-pass,
path chunk, visibility span) began after the signal but the one it landed in. The driver holds
the process at each point: no case depends on the machine's speed. The scenes are 16x16 at 4 spp.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import EXIT_HANGUP, EXIT_INTERRUPTED, EXIT_TERMINATED
from sensaov_cli.outputs.atomic import TEMPORARY_SUFFIX
from sensaov_cli.outputs.exr import read_exr

from .conftest import ROOT, sensaov, write_job

DRIVER = Path(__file__).with_name("signal_driver.py")
# One batch: a stop is held at the second chunk of a pass, and the driver's lowered chunk limits
# give a 16x16 pass of 4 spp several (a batch of 1 spp would have one).
RENDER = {"spp": 4, "max_depth": 3, "seed": 0, "resolution": [16, 16], "batches": 1}


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


def driven(
    job: Path, command: list[str], point: str, sig: str
) -> tuple[subprocess.CompletedProcess[str], int | None]:
    """``command`` on ``job`` through the driver; the chunks begun after the signal (None: the
    signal was never sent)."""
    stamp = job.parent / "stamp"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    args = [sys.executable, str(DRIVER), point, sig, str(stamp), *command, str(job)]
    result = subprocess.run(args, capture_output=True, text=True, env=env, timeout=300)
    return result, int(stamp.read_text()) if stamp.exists() else None


def interrupted(
    tmp_path: Path, previous: Path, command: list[str], point: str, sig: str
) -> tuple[subprocess.CompletedProcess[str], dict[str, bytes], int | None]:
    job = write_job(tmp_path, render=RENDER)
    shutil.copytree(previous, tmp_path / "out")
    result, chunks = driven(job, command, point, sig)
    return result, snapshot(tmp_path / "out"), chunks


def check_outcome(
    result: subprocess.CompletedProcess[str],
    before: dict[str, bytes],
    after: dict[str, bytes],
    sig: str,
    chunks: int | None,
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
    assert chunks is not None and chunks <= 1, chunks  # the signal came; it stopped the work
    return replaced


RUN_CASES = [
    # point (signal_driver.py), signal, what must have been replaced
    ("stage:load_s", "TERM", set()),  # before Mitsuba is imported
    ("import:mitsuba", "TERM", set()),  # during Mitsuba's import, the scene load's first act
    ("pass:primal_s", "TERM", set()),  # in the middle of the primal render
    ("pass:backward_", "TERM", set()),
    ("pass:backward_", "INT", set()),
    ("pass:backward_", "HUP", set()),  # a closed terminal: a stop like the others
    ("rename", "HUP", {"buffer.npz", "primal.exr"}),
    ("write:1", "TERM", set()),  # the buffer half written
    ("write:2", "TERM", set()),  # the buffer complete, the primal EXR half written
    ("rename", "TERM", {"buffer.npz", "primal.exr"}),  # both renamed together
    ("pass:primal_s", "KILL", set()),
    ("write:2", "KILL", set()),
    ("rename", "KILL", {"buffer.npz"}),  # killed between the two renames
]


@pytest.mark.parametrize(("point", "sig", "expected"), RUN_CASES)
def test_run_stopped(
    tmp_path: Path, previous: Path, point: str, sig: str, expected: set[str]
) -> None:
    result, after, chunks = interrupted(tmp_path, previous, ["run", "-q"], point, sig)
    replaced = check_outcome(result, snapshot(previous), after, sig, chunks)
    if sig != "KILL" or point != "rename":
        assert replaced == expected, result.stderr
    else:  # SIGKILL lands before the first rename or between the two: either is whole
        assert replaced <= {"buffer.npz", "primal.exr"}


PROJECT_CASES = [
    ("import:mitsuba", "TERM", set()),
    ("stage:view_", "TERM", set()),  # as the objective camera's view begins (the middle of a
    ("stage:view_", "HUP", set()),  # view: test_sigterm_in_a_pass_ends_within_one_chunk)
    ("write:1", "TERM", set()),  # the camera's EXR half written
    ("write:3", "TERM", {"objective.exr", "previews/objective/mean_luma.objects.png"}),
    ("rename", "TERM", {"objective.exr"}),
    ("write:3", "KILL", {"objective.exr", "previews/objective/mean_luma.objects.png"}),
]


@pytest.mark.parametrize(("point", "sig", "expected"), PROJECT_CASES)
def test_project_stopped(
    tmp_path: Path, previous: Path, point: str, sig: str, expected: set[str]
) -> None:
    command = ["project", "-q", "--png", "--beauty-spp", "1"]
    result, after, chunks = interrupted(tmp_path, previous, command, point, sig)
    replaced = check_outcome(result, snapshot(previous), after, sig, chunks)
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
    result, after, chunks = interrupted(tmp_path, previous, ["report"], "written", sig)
    code = {"TERM": EXIT_TERMINATED, "HUP": EXIT_HANGUP}[sig]
    report = tmp_path / "out" / "report.html"
    assert result.returncode == code, result.stderr
    line = result.stderr.strip()
    assert "\n" not in line and line.startswith(f"sensaov: error: stopped by SIG{sig}"), line
    assert line.endswith(f"; replaced: {report}; no other output was touched"), line
    assert after["report.html"].rstrip().endswith(b"</html>")
    assert not [name for name in after if name.endswith(TEMPORARY_SUFFIX)]
    assert chunks == 0  # sent after the report was written


@pytest.mark.parametrize(
    ("module", "code"),
    [
        ("sensaov_cli.interrupts", -signal.SIGTERM),  # before sensaov's first line
        ("click", EXIT_TERMINATED),  # the command line's imports
        ("sensaov_cli.cli.options", EXIT_TERMINATED),
        ("numpy", EXIT_TERMINATED),  # the command's own imports
    ],
)
def test_sigterm_while_the_interpreter_imports(
    tmp_path: Path, previous: Path, module: str, code: int
) -> None:
    """Before sensaov's first line the default action ends the process (the shell says 143);
    from then on the signal is recorded and the command exits 143 with its one line."""
    job = write_job(tmp_path, render=RENDER)
    shutil.copytree(previous, tmp_path / "out")
    result, _ = driven(job, ["run", "-q"], f"import:{module}", "TERM")
    assert result.returncode == code, result.stderr
    assert "Traceback" not in result.stderr and "terminate" not in result.stderr
    line = "sensaov: error: stopped by SIGTERM; no output was replaced\n"
    assert result.stderr == ("" if code < 0 else line)
    assert snapshot(tmp_path / "out") == snapshot(previous)


VIEW_CAMERA = {
    "name": "big",
    "look_at": {"origin": [0, 0, 3.9], "target": [0, 0, 0], "up": [0, 1, 0]},
    "resolution": [32, 32],
    "vis_spp": 4,
}


@pytest.mark.parametrize(
    ("command", "stage", "job"),
    [
        (["run", "-q"], "backward_", {}),  # prb's backward sub-passes
        (["run", "-q"], "primal_s", {}),
        (["run", "-q"], "forward_", {"forward": [{"name": "light", "object": "light"}]}),
        (  # the visibility pass with UVs that texel fields are painted through (project traces
            # every camera in its shared stage, for the display scales, before any view)
            ["project", "-q", "--beauty-spp", "1"],
            "visibility",
            {"inspection_cameras": [VIEW_CAMERA], "channels": [{"name": "t", "kind": "texel"}]},
        ),
        (["project", "-q"], "view_", {"inspection_cameras": [VIEW_CAMERA]}),
    ],
    ids=["backward", "primal", "forward", "texel", "view"],
)
def test_sigterm_in_a_pass_ends_within_one_chunk(
    tmp_path: Path, command: list[str], stage: str, job: dict[str, object]
) -> None:
    """SIGTERM lands at the start of a pass's second chunk (sub-pass of the primal, backward or
    forward pass; span of a visibility trace) with its raise lost, as when it surfaces inside a
    kernel's callback: the stop check between chunks ends the pass before a third one begins
    (docs/exit-codes.md). The driver splits the 16x16 job into several chunks."""
    path = write_job(tmp_path, **{"render": RENDER, **job})
    if command[0] == "project":  # its buffer first
        assert sensaov("run", "-q", str(path)).returncode == 0
    result, chunks = driven(path, command, f"pass:{stage}", "TERM")
    assert result.returncode == EXIT_TERMINATED, result.stderr
    assert result.stderr.strip().splitlines()[-1].startswith("sensaov: error: stopped by SIGTERM")
    assert chunks == 1, f"{chunks} chunks began after SIGTERM"  # the one it landed in
    if command[0] == "run":
        assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())
