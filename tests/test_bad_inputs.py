"""The bad-input corpus (tests/data/bad/): every case exits with its documented code, says so in
one line, prints no traceback and writes nothing. Jobs and scenes go to ``validate`` or ``run``,
masks and targets to ``run`` (refused before rendering), buffers to ``rank`` and ``project``.
A second corpus breaks a finished project one thing at a time (tests/hostile_workspace.py: an
output onto an input, special files, shard metadata, corrupt EXRs, odd command-line values,
closed pipes, links that lead nowhere, memory settings) and asserts the same of every command.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from sensaov_cli.errors import EXIT_BAD_INPUT
from tests.bad_buffers import write_buffer

from .bad_buffers import MAKERS, STRICT_READER, good_buffer
from .conftest import ROOT, SCENES, sensaov
from .hostile_workspace import HOSTILE, Hostile, make_workspace

CORPUS = Path(__file__).parent / "data" / "bad"
SCENE = SCENES / "cbox" / "scene.xml"


@dataclass(frozen=True)
class Case:
    id: str
    command: str
    file: str  # a corpus file, or a kind made at test time ("fifo", "dev", "dir", "buffer:...")
    extra: str = ""  # the scene, mask or target the corpus job names
    codes: tuple[int, ...] = (EXIT_BAD_INPUT,)
    timeout: float = 30  # a hang is a failure (the longest case, a Mitsuba load, takes ~2 s)


JOBS = [
    Case(name.stem, "validate", name.name)
    for name in sorted(CORPUS.glob("job_*.yaml"))
    if name.stem not in {"job_mask_missing", "job_python_not_allowed"}
] + [
    Case("job_mask_missing", "run", "job_mask_missing.yaml"),
    Case("job_python_not_allowed", "run", "job_python_not_allowed.yaml"),
    Case("job is a FIFO", "run", "fifo"),
    Case("job is a device", "run", "dev"),
    Case("job is a directory", "run", "dir"),
]
SCENE_CASES = [
    Case(name.stem, "run", "scene_job.yaml", extra=name.name)
    for name in sorted(CORPUS.glob("scene_*.xml"))
] + [Case("scene is a FIFO", "run", "scene_job.yaml", extra="fifo")]
IMAGES = [
    Case(name.stem, "run", "mask_job.yaml", extra=name.name)
    for name in sorted(CORPUS.glob("mask_*.exr"))
] + [
    Case(name.stem, "run", "target_job.yaml", extra=name.name)
    for name in sorted(CORPUS.glob("target_*.exr"))
]
BUFFERS = [Case(f"buffer {name}", "rank", f"buffer:{name}") for name in MAKERS] + [
    Case("buffer.npz is a directory", "rank", "buffer:dir"),
    Case("project: buffer.npz is a directory", "project", "buffer:dir"),
]
STRICT = [
    pytest.param(Case(f"buffer {name}", "rank", f"buffer:{name}"), id=f"buffer {name}")
    for name in STRICT_READER
] + [
    pytest.param(  # a reader that opens it waits for a writer forever
        Case("buffer.npz is a FIFO", "rank", "buffer:fifo", timeout=5),
        id="buffer.npz is a FIFO",
    )
]
ALL = JOBS + SCENE_CASES + IMAGES + BUFFERS


def test_the_corpus_has_at_least_40_cases() -> None:
    assert len(ALL) + len(STRICT) >= 40


def listing(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): p.lstat().st_size for p in sorted(root.rglob("*"))}


def prepare(case: Case, tmp: Path) -> list[str]:
    """The case's files in ``tmp``; returns the command's arguments."""
    if case.file.startswith("buffer:"):
        kind = case.file.split(":", 1)[1]
        buffer = tmp / "buffer.npz"
        if kind == "dir":
            buffer.mkdir()
        elif kind == "fifo":
            os.mkfifo(buffer)
        else:
            good = tmp / "good.npz"
            write_buffer(good, good_buffer())
            (MAKERS | STRICT_READER)[kind](good, buffer)
            good.unlink()
        if case.command == "project":
            job = _job(tmp, "scene_job.yaml", str(SCENE))
            return ["project", str(job), "--buffer", str(buffer)]
        return ["rank", str(buffer)]
    if case.file in ("fifo", "dev", "dir"):
        job = tmp / "job.yaml"
        {"fifo": os.mkfifo, "dev": lambda p: os.symlink("/dev/zero", p), "dir": os.mkdir}[
            case.file
        ](job)
        return [case.command, str(job)]
    extra = ""
    if case.extra == "fifo":
        extra = str(tmp / "scene.xml")
        os.mkfifo(extra)
    elif case.extra.endswith(".xml"):  # a corpus scene may name a file beside it as HERE/...
        text = (CORPUS / case.extra).read_text().replace("HERE", str(CORPUS))
        (tmp / case.extra).write_text(text)
        extra = str(tmp / case.extra)
    elif case.extra:
        extra = str(shutil.copy(CORPUS / case.extra, tmp / case.extra))
    return [case.command, str(_job(tmp, case.file, extra))]


def _job(tmp: Path, name: str, extra: str) -> Path:
    text = (CORPUS / name).read_text(errors="surrogateescape")
    for word, value in (
        ("SCENEFILE", extra), ("MASKFILE", extra), ("SCENE", str(SCENE)),
        ("HERE", str(CORPUS)), ("OUT", str(tmp / "out")),
    ):  # fmt: skip
        text = text.replace(word, value)
    job = tmp / "job.yaml"
    job.write_text(text, errors="surrogateescape")
    return job


def check(case: Case, tmp: Path) -> None:
    args = prepare(case, tmp)
    if args[0] in ("run", "project"):
        args.insert(1, "-q")  # progress lines are not the error
    before, corpus_before = listing(tmp), listing(CORPUS)
    if _may_hang(case.file, case.extra):  # a regression must time out, not hang the test run
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        result = subprocess.run(
            [sys.executable, "-m", "sensaov_cli", *args],
            capture_output=True,
            text=True,
            env=env,
            timeout=case.timeout,
            cwd=tmp,
        )
    else:
        result = sensaov(*args, cwd=tmp)
    assert result.returncode in case.codes, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("sensaov: error: "), result.stderr
    assert "Traceback" not in result.stderr and "internal error" not in result.stderr
    assert listing(tmp) == before and listing(CORPUS) == corpus_before


def _may_hang(*files: str) -> bool:
    """A FIFO or a device: a reader that opens one by mistake waits forever."""
    return any(name in ("fifo", "dev", "buffer:fifo") for name in files)


@pytest.mark.parametrize("case", ALL, ids=lambda c: c.id)
def test_bad_input_is_refused(tmp_path: Path, case: Case) -> None:
    check(case, tmp_path)


@pytest.mark.parametrize("case", STRICT)
def test_bad_buffer_the_strict_reader_refuses(tmp_path: Path, case: Case) -> None:
    check(case, tmp_path)


# --- a finished project, broken one thing at a time (tests/hostile_workspace.py) ------------


@pytest.fixture(scope="session")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_workspace(tmp_path_factory.mktemp("workspace"))


def state(root: Path) -> dict[str, object]:
    """What is on disk under ``root``, links and special files included (never opened)."""
    found: dict[str, object] = {}
    for path in sorted(root.rglob("*")):
        info = path.lstat()
        name = str(path.relative_to(root))
        if stat.S_ISLNK(info.st_mode):
            found[name] = ("link", os.readlink(path))
        elif stat.S_ISREG(info.st_mode):
            small = info.st_size < 1 << 22
            found[name] = (info.st_size, info.st_mode, path.read_bytes() if small else None)
        else:
            found[name] = (stat.S_IFMT(info.st_mode),)
    return found


def test_the_workspace_corpus_has_its_cases() -> None:
    assert len(HOSTILE) >= 60
    assert sum("(new)" in case.id for case in HOSTILE) >= 20


@pytest.mark.parametrize("case", HOSTILE, ids=lambda c: c.id)
def test_a_hostile_workspace_is_refused(workspace: Path, tmp_path: Path, case: Hostile) -> None:
    ws = tmp_path / "ws"
    shutil.copytree(workspace, ws, symlinks=True)
    args = case.build(ws)
    before = state(ws)
    if case.stdout == "pipe" and not case.env and case.timeout >= 60 and args[0] != "view":
        result = sensaov(*args, cwd=ws)  # nothing to hang on or serve, no process setting
    else:
        result = _in_a_process(ws, case, args)
    assert result.returncode in case.codes, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("sensaov: error: "), result.stderr
    assert "Traceback" not in result.stderr and "internal error" not in result.stderr
    assert lines[0].endswith("; no output was replaced"), lines[0]
    assert state(ws) == before


def _in_a_process(ws: Path, case: Hostile, args: list[str]) -> subprocess.CompletedProcess[str]:
    """The executable, for a closed or abandoned stdout, an environment, or a possible hang."""
    command = [sys.executable, "-m", "sensaov_cli", *args]
    env = {**os.environ, "PYTHONPATH": str(ROOT), **case.env}
    if case.stdout == "closed":
        command = ["sh", "-c", 'exec "$@" >&-', "sh", *command]
    reader, writer = os.pipe()
    if case.stdout == "gone":
        os.close(reader)
    try:
        result = subprocess.run(
            command,
            cwd=ws,
            env=env,
            stdout=writer if case.stdout == "gone" else subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            timeout=case.timeout,
        )
    finally:
        os.close(writer)
        if case.stdout != "gone":
            os.close(reader)
    return result
