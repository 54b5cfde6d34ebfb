"""Smaller defects adversarial trials found, one test each: what a command prints, keeps and blames.

The classes with many cases (outputs onto inputs, special files, metadata, memory, pipes) are
in the bad-input corpus (test_bad_inputs.py); the stops in test_signals.py. Here: replaced files
keep their mode, exit 2 never follows a write, broken previews are named on the report,
matplotlib writes nothing under $HOME, a Python objective's print stays off ``run --json``,
``--resume`` re-renders a cut primal, errors name the file at fault, and a FIFO forward sidecar
is refused rather than waited on.
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from sensaov_cli.errors import EXIT_BAD_INPUT, EXIT_JOB_FAILED, BufferFormatError
from sensaov_cli.outputs import atomic

from .conftest import ROOT, sensaov, use_scene, write_job

CORPUS = Path(__file__).parent / "data" / "bad"
RENDER = {"spp": 2, "max_depth": 3, "seed": 0, "resolution": [16, 16]}


@pytest.fixture(scope="module")
def project(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A job after ``run`` and ``project --png`` (16x16, 2 spp); returns the job file."""
    job = write_job(tmp_path_factory.mktemp("project"), render=RENDER)
    for command in (["run", "-q"], ["project", "-q", "--png", "--beauty-spp", "1"]):
        done = sensaov(*command, str(job))
        assert done.returncode == 0, done.stderr
    return job


def test_a_replaced_file_keeps_its_mode_and_a_new_one_gets_the_usual(tmp_path: Path) -> None:
    private, fresh = tmp_path / "private.bin", tmp_path / "fresh.bin"
    private.write_bytes(b"old")
    private.chmod(0o600)
    atomic.atomic_write(private, lambda tmp: tmp.write_bytes(b"new"))
    atomic.atomic_write(fresh, lambda tmp: tmp.write_bytes(b"new"))
    umask = os.umask(0)
    os.umask(umask)
    assert private.read_bytes() == b"new"
    assert stat.S_IMODE(private.stat().st_mode) == 0o600
    assert stat.S_IMODE(fresh.stat().st_mode) == 0o666 & ~umask  # not mkstemp's 0600


def test_exit_2_is_never_the_code_once_an_output_was_replaced(tmp_path: Path) -> None:
    """Exit 2 promises nothing was written: a bad input found after a write ends with 1, and
    the line names what was replaced."""
    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "from sensaov_cli.cli import options\n"
        "from sensaov_cli.outputs.atomic import atomic_write\n"
        f"atomic_write(Path({str(tmp_path / 'a.txt')!r}), lambda t: t.write_text('x'))\n"
        "options._fail('a bad value', 2)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert done.returncode == EXIT_JOB_FAILED, done.stderr
    assert done.stderr.strip().endswith(
        f"replaced: {tmp_path / 'a.txt'}; no other output was touched"
    )


def test_broken_previews_are_named_on_the_report_not_embedded(
    project: Path, tmp_path: Path
) -> None:
    previews = project.parent / "out" / "previews"
    good = next(previews.rglob("*.png"))
    (previews / "empty.png").write_bytes(b"")
    (previews / "cut.png").write_bytes(good.read_bytes()[:60])
    (previews / "nowhere.png").symlink_to("missing.png")
    try:
        done = sensaov("report", str(project), "-o", str(tmp_path / "r.html"))
        assert done.returncode == 0, done.stderr
        page = (tmp_path / "r.html").read_text()
    finally:
        for name in ("empty.png", "cut.png", "nowhere.png"):
            (previews / name).unlink()
    for name in ("empty.png", "cut.png", "nowhere.png"):
        assert name in page
    assert page.count("data:image/png;base64,") >= 1  # the good previews are still embedded
    assert "Traceback" not in done.stderr


def test_matplotlib_writes_nothing_under_home(project: Path, tmp_path: Path) -> None:
    home = tmp_path / "home"
    home.mkdir()
    home.chmod(0o500)  # read-only, as on some farms: matplotlib would warn about it
    env = {k: v for k, v in os.environ.items() if k not in ("MPLCONFIGDIR", "XDG_CACHE_HOME")}
    env.update(HOME=str(home), PYTHONPATH=str(ROOT))
    buffer = project.parent / "out" / "buffer.npz"
    done = subprocess.run(
        [sys.executable, "-m", "sensaov_cli", "sunburst", str(buffer), "-o", "s.png"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=env,
    )
    home.chmod(0o700)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""  # no cache warning, no glyph warnings
    assert list(home.iterdir()) == []


def test_a_python_objectives_print_does_not_corrupt_run_json(tmp_path: Path) -> None:
    (tmp_path / "noisy.py").write_text(
        "import drjit as dr\n"
        "def f(image):\n"
        "    print('hello from the objective')\n"
        "    return dr.mean(image, axis=None)\n"
    )
    job = write_job(
        tmp_path,
        render=RENDER,
        objectives=[{"name": "noisy", "type": "python", "function": "noisy:f"}],
    )
    done = sensaov("run", "--json", "--allow-python", str(job))
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)  # nothing but the summary on stdout
    assert "hello from the objective" in done.stderr


def test_resume_renders_a_cut_primal_again(tmp_path: Path) -> None:
    job = write_job(tmp_path, render=RENDER)
    assert sensaov("run", "-q", str(job)).returncode == 0
    primal = tmp_path / "out" / "primal.exr"
    primal.write_bytes(primal.read_bytes()[: primal.stat().st_size // 2])
    done = sensaov("run", "--resume", str(job))
    assert done.returncode == 0, done.stderr
    assert "skipped (--resume)" not in done.stderr
    from sensaov_cli.outputs.exr import read_exr

    read_exr(primal)  # whole again


@pytest.mark.parametrize(
    ("scene", "named"),
    [
        ("scene_ply_truncated.xml", "ply_billion_vertices.ply"),  # the mesh, not scene.xml
        ("scene_nan.xml", "reflectance"),
        ("scene_inf.xml", "radius"),
        ("scene_float32_overflow.xml", "1e39"),
    ],
)
def test_an_error_names_the_file_and_value_at_fault(tmp_path: Path, scene: str, named: str) -> None:
    text = (CORPUS / scene).read_text().replace("HERE", str(CORPUS))
    (tmp_path / scene).write_text(text)
    job = write_job(tmp_path)
    use_scene(job, tmp_path / scene)
    done = sensaov("validate", str(job))
    assert done.returncode == EXIT_BAD_INPUT, done.stderr
    assert named in done.stderr, done.stderr
    if scene != "scene_ply_truncated.xml":
        assert f"{scene}:" in done.stderr  # with its line


def test_a_forward_sidecar_that_is_a_fifo_is_refused_not_waited_on(tmp_path: Path) -> None:
    from sensaov_cli.buffer.forward_sidecar import read_forward

    os.mkfifo(tmp_path / "forward.npz")
    with pytest.raises(BufferFormatError, match="FIFO"):
        read_forward(tmp_path / "forward.npz")


@pytest.mark.parametrize("stderr", ["closed", "gone"])
def test_a_closed_stderr_drops_progress_and_the_run_goes_on(tmp_path: Path, stderr: str) -> None:
    """stderr is for people: closed (``2>&-``) or read by nobody, the work is still done."""
    job = write_job(tmp_path, render=RENDER)
    command = [sys.executable, "-m", "sensaov_cli", "run", "--progress", "farm", str(job)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    if stderr == "closed":
        done = subprocess.run(
            ["sh", "-c", 'exec "$@" 2>&-', "sh", *command], capture_output=False,
            stdout=subprocess.DEVNULL, env=env, timeout=300,
        )  # fmt: skip
    else:
        reader, writer = os.pipe()
        os.close(reader)
        try:
            done = subprocess.run(
                command, stdout=subprocess.DEVNULL, stderr=writer, env=env, timeout=300
            )
        finally:
            os.close(writer)
    assert done.returncode == 0
    assert (tmp_path / "out" / "buffer.npz").is_file()
    assert (tmp_path / "out" / "primal.exr").is_file()
    assert not list((tmp_path / "out").glob(".*.partial"))
