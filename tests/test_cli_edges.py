"""The command line's own edges: an empty path, a result stdout cannot take."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from .conftest import sensaov

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    "arguments",
    [["run", ""], ["validate", " "], ["rank", ""], ["merge", "", "-o", "x.npz"], ["report", ""]],
)
def test_an_empty_path_is_named_as_empty_not_as_the_current_folder(
    arguments: list[str], tmp_path: Path
) -> None:
    done = sensaov(*arguments, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "the path is empty" in lines[0], done.stderr
    assert "directory" not in lines[0] and "Traceback" not in done.stderr
    assert not list(tmp_path.iterdir())


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs Linux's /dev/full")
@pytest.mark.parametrize(
    "arguments", [["schema"], ["validate", str(ROOT / "configs" / "cbox.yaml")]]
)
def test_a_result_stdout_cannot_take_is_blamed_on_stdout(arguments: list[str]) -> None:
    with open("/dev/full", "w") as full:
        done = subprocess.run(
            [sys.executable, "-m", "sensaov_cli", *arguments],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
        )
    assert done.returncode == 1, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr  # no second complaint from the interpreter's exit
    assert lines[0].startswith("sensaov: error: stdout: cannot write the result: disk full")


@pytest.mark.parametrize(("arguments", "code"), [(["schema"], 0), (["rank", "missing.npz"], 2)])
def test_the_executable_ends_when_its_command_does(
    arguments: list[str], code: int, tmp_path: Path
) -> None:
    """After a command, the executable flushes and exits with its code, without the
    interpreter's finalisation (0.15 s of Dr.Jit and module teardown in which a farm's SIGTERM
    found Python's handlers already gone and killed a finished process, status -15): an
    atexit callback, which finalisation would run, never runs; every line still arrives; the
    scratch folders sensaov's own exit handler removes are removed."""
    marker, scratch = tmp_path / "finalised", tmp_path / "scratch"
    script = (
        "import atexit, pathlib\n"
        f"atexit.register(pathlib.Path({str(marker)!r}).write_text, 'yes')\n"
        "from sensaov_cli.outputs.atomic import scratch_folder\n"  # as a sunburst makes one
        f"pathlib.Path({str(scratch)!r}).write_text(str(scratch_folder('test')))\n"
        "from sensaov_cli.cli import console\n"
        "console()\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, *arguments],
        capture_output=True, text=True, cwd=tmp_path, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == code, done.stderr
    assert not marker.exists()
    assert not Path(scratch.read_text()).exists()  # sensaov's own exit handler still ran
    if code == 0:
        assert done.stdout.rstrip().endswith("}")  # the whole JSON schema, flushed
    else:
        assert done.stderr.count("\n") == 1 and "missing.npz" in done.stderr
