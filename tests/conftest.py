"""Shared fixtures. Renders are expensive: anything rendered is session-scoped and tiny.

Commands run in this process (:func:`sensaov`), which imports Mitsuba and compiles its kernels
once for the whole run; :func:`sensaov_process` starts the executable, for the tests whose
subject is the process itself (signals, its exit, closed pipes, start-up, fresh imports).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import warnings
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from types import ModuleType
from typing import IO

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"


@pytest.fixture(scope="session")
def mi() -> ModuleType:
    from sensaov_cli.render.runtime import import_mitsuba

    return import_mitsuba("llvm_ad_rgb")


def write_job(folder: Path, scene: str = "cbox", **overrides: object) -> Path:
    """A small job on a shipped scene (24x24, 16 spp), written to ``folder/job.yaml``.

    One batch unless a test asks for more: most tests look at views, tables and files, where
    eight batches of 2 spp would only multiply each pass's fixed cost. The default (``auto``)
    and what errors change are tested where they are the subject (test_until, test_resolution,
    test_default_errors)."""
    job: dict[str, object] = {
        "version": 1,
        "scene": str(SCENES / scene / "scene.xml"),
        "variant": "llvm_ad_rgb",
        "render": {"spp": 16, "max_depth": 6, "seed": 0, "resolution": [24, 24], "batches": 1},
        "objectives": [{"name": "mean_luma", "type": "mean_luminance"}],
        "output": str(folder / "out"),
    }
    job.update(overrides)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "job.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    return path


@pytest.fixture(scope="session")
def job_writer(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., Path]:
    def make(name: str, scene: str = "cbox", **overrides: object) -> Path:
        return write_job(tmp_path_factory.mktemp(name), scene, **overrides)

    return make


def sensaov_process(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """Run the command line as a user would, in a fresh process."""
    return subprocess.run(
        [sys.executable, "-m", "sensaov_cli", *args], cwd=cwd, capture_output=True, text=True
    )


def sensaov(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """Run the command line in this process, with what :func:`sensaov_process` would report.

    As the executable (``cli.console``) does: ``main``, its exit code (0 for none), sensaov's
    scratch folders removed. Both standard descriptors go to files for the call, so what
    Python prints and what Mitsuba or LLVM write to descriptor 1 or 2 arrive in one stream each,
    in order; warnings print as in a fresh interpreter. The ledger of replaced outputs starts
    empty, as a process's does (the one line names what this command replaced, and a bad input
    found before any write keeps exit 2). The process's own state is put back after: signal
    handlers, working folder, ``sys.path`` and the modules a Python objective imported from a
    folder it added there (the next job may name another module alike).
    """
    from sensaov_cli.outputs import atomic
    from sensaov_cli.outputs.atomic import remove_temporaries

    atomic._replaced.clear()
    with ExitStack() as stack:
        out, err = (stack.enter_context(tempfile.TemporaryFile()) for _ in range(2))
        with _process_state(cwd), _standard_streams(out, err):
            from sensaov_cli.cli import main

            try:
                main(args=list(args), prog_name="sensaov")
                code = 0
            except SystemExit as done:
                code = 0 if done.code is None else done.code
                if not isinstance(code, int):  # Python prints the message and exits 1
                    print(code, file=sys.stderr)
                    code = 1
            finally:
                remove_temporaries()
        stdout, stderr = (_text(stream) for stream in (out, err))
    return subprocess.CompletedProcess(["sensaov", *args], code, stdout, stderr)


@contextmanager
def _process_state(cwd: Path | None) -> Iterator[None]:
    handlers = {signum: signal.getsignal(signum) for signum in _STOP_SIGNALS}
    folder, path, modules = os.getcwd(), list(sys.path), set(sys.modules)
    if cwd is not None:
        os.chdir(cwd)
    try:
        with warnings.catch_warnings():
            warnings.resetwarnings()
            for category in _IGNORED_WARNINGS:  # a fresh interpreter's default filters
                warnings.simplefilter("ignore", category)
            warnings.filterwarnings("default", category=DeprecationWarning, module="__main__")
            warnings.showwarning = warnings._showwarning_orig  # type: ignore[attr-defined]
            yield
    finally:
        os.chdir(folder)
        added = [entry for entry in sys.path if entry not in path]
        sys.path[:] = path
        for name in set(sys.modules) - modules:
            source = getattr(sys.modules[name], "__file__", None) or ""
            if any(source.startswith(entry + os.sep) for entry in added):
                del sys.modules[name]
        for signum, handler in handlers.items():
            signal.signal(signum, handler)


_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
_IGNORED_WARNINGS = (ResourceWarning, ImportWarning, PendingDeprecationWarning, DeprecationWarning)


@contextmanager
def _standard_streams(out: IO[bytes], err: IO[bytes]) -> Iterator[None]:
    """Descriptors 1 and 2 into ``out`` and ``err``; ``sys.stdout``/``sys.stderr`` written as a
    subprocess's are (UTF-8, stdout buffered, stderr line-buffered with backslash escapes)."""
    streams = sys.stdout, sys.stderr
    for stream in streams:
        stream.flush()
    saved = [os.dup(descriptor) for descriptor in (1, 2)]
    os.dup2(out.fileno(), 1)
    os.dup2(err.fileno(), 2)
    sys.stdout = open(1, "w", encoding="utf-8", closefd=False)
    sys.stderr = open(2, "w", encoding="utf-8", errors="backslashreplace", closefd=False)
    sys.stderr.reconfigure(line_buffering=True)
    try:
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.close()  # flushed; the descriptor stays open (closefd=False)
            except (OSError, ValueError):
                pass
        sys.stdout, sys.stderr = streams
        for descriptor, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, descriptor)
            os.close(copy)


def _text(stream: IO[bytes]) -> str:
    """What a subprocess's ``text=True`` reads: UTF-8, universal newlines."""
    stream.seek(0)
    return stream.read().decode("utf-8").replace("\r\n", "\n").replace("\r", "\n")


def use_scene(job: Path, scene: Path) -> None:
    """Point a job ``write_job`` wrote at a scene outside ``scenes/`` (a test's own)."""
    data = yaml.safe_load(job.read_text())
    data["scene"] = str(scene)
    job.write_text(yaml.safe_dump(data, sort_keys=False))
