"""A disk that fills during ``run`` and ``project --png``: exit 1, nothing partial, the previous
files intact, and the one line says which outputs (if any) were replaced before it filled.

The disk is a real tmpfs (mounted here, which needs root: the suite runs as root in this
project's CI; elsewhere the test says why it cannot run). It is sized to hold the previous
outputs and a few KiB more, so the new files' temporaries cannot all fit.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from sensaov_cli.errors import EXIT_JOB_FAILED

from .conftest import sensaov, write_job
from .test_signals import RENDER, loadable, snapshot

PAGE = 4096


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    mount = tmp_path / "disk"
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(mount)])
    if done.returncode != 0:
        pytest.skip("this container cannot mount a tmpfs")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=True)


def fill_up(mount: Path, slack_pages: int) -> None:
    """Shrink the tmpfs to what it holds now plus ``slack_pages`` pages."""
    stats = os.statvfs(mount)
    used = (stats.f_blocks - stats.f_bfree) * stats.f_frsize
    size = used + slack_pages * PAGE
    subprocess.run(["mount", "-o", f"remount,size={size}", str(mount)], check=True)


@pytest.fixture(scope="module")
def previous(tmp_path_factory: pytest.TempPathFactory) -> Path:
    job = write_job(tmp_path_factory.mktemp("previous"), render=RENDER)
    for command in (["run", "-q"], ["project", "-q", "--png", "--beauty-spp", "1"]):
        result = sensaov(*command, str(job))
        assert result.returncode == 0, result.stderr
    return job.parent / "out"


def check_full(
    result: subprocess.CompletedProcess[str], out: Path, before: dict[str, bytes]
) -> str:
    assert result.returncode == EXIT_JOB_FAILED, result.stderr
    line = result.stderr.strip()
    assert "\n" not in line and "Traceback" not in line and "internal error" not in line, line
    assert "disk full" in line or "No space left on device" in line, line
    after = snapshot(out)
    assert not [name for name in after if name.endswith(".partial")], after
    assert set(after) == set(before)
    for name, data in after.items():
        if data != before[name]:
            assert str(out / name) in line, (name, line)
            loadable(out / name)
    return line


@pytest.mark.parametrize("slack_pages", [0, 2])
def test_run_on_a_full_disk(
    tmp_path: Path, small_disk: Path, previous: Path, slack_pages: int
) -> None:
    out = small_disk / "out"
    shutil.copytree(previous, out)
    job = write_job(tmp_path / "job", render=RENDER, output=str(out))
    before = snapshot(out)
    fill_up(small_disk, slack_pages)
    line = check_full(sensaov("run", "-q", str(job)), out, before)
    assert line.endswith("no output was replaced"), line
    assert snapshot(out) == before


@pytest.mark.parametrize("slack_pages", [0, 1, 3])
def test_project_png_on_a_full_disk(
    tmp_path: Path, small_disk: Path, previous: Path, slack_pages: int
) -> None:
    """With a little room the camera's EXR may fit and a PNG not: both cases are reported."""
    out = small_disk / "out"
    shutil.copytree(previous, out)
    job = write_job(tmp_path / "job", render=RENDER, output=str(out))
    before = snapshot(out)
    fill_up(small_disk, slack_pages)
    result = sensaov("project", "-q", "--png", "--beauty-spp", "1", str(job))
    check_full(result, out, before)
