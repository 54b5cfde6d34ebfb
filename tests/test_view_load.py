"""``sensaov view`` as a process under load: signals during concurrent requests, its memory
budget, ``--open``.

Each test starts the real command (the subject is the process: its signals, its resident
memory, the browser it launches) on one small buffer, and waits on what the process prints,
never on the clock (timeouts only bound a failure).
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import yaml

from sensaov_cli import interrupts
from sensaov_cli.errors import EXIT_TERMINATED
from sensaov_cli.job.load import load_job
from sensaov_cli.views.coverage import Coverage, VisibilityPass

from .conftest import ROOT, sensaov

DRIVER = Path(__file__).with_name("signal_driver.py")
BOUND_S = 120  # a failure bound only: every wait below ends on an event long before


@pytest.fixture(scope="module")
def small_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo job at 24x24 and 4 spp, with its buffer made."""
    folder = tmp_path_factory.mktemp("view-load")
    data = yaml.safe_load((ROOT / "configs" / "cbox.yaml").read_text())
    data["scene"] = str(ROOT / "scenes" / "cbox" / "scene.xml")
    data["variant"] = "llvm_ad_rgb"
    data["render"].update(spp=4, resolution=[24, 24])
    data["output"] = str(folder / "out")
    job = folder / "job.yaml"
    job.write_text(yaml.safe_dump(data, sort_keys=False))
    result = sensaov("run", "-q", str(job))
    assert result.returncode == 0, result.stderr
    return job


@contextmanager
def serving(
    args: list[str], env: dict[str, str] | None = None
) -> Iterator[tuple[subprocess.Popen[str], str, queue.Queue[str]]]:
    """The process, its URL, and a queue of the rest of its stdout lines (read by a thread)."""
    process = subprocess.Popen(
        args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})},
    )  # fmt: skip
    assert process.stdout is not None
    lines: queue.Queue[str] = queue.Queue()
    url = process.stdout.readline().strip()
    reader = threading.Thread(target=lambda: [lines.put(line) for line in process.stdout or ()])
    reader.start()
    try:
        assert url.startswith("http://"), process.stderr.read() if process.stderr else ""
        yield process, url, lines
    finally:
        if process.poll() is None:
            process.kill()
        process.wait()
        reader.join()


def fetch(url: str, method: str = "GET") -> tuple[int, bytes]:
    request = urllib.request.Request(url, method=method, headers={"X-Sensaov": "1"})
    try:
        with urllib.request.urlopen(request, timeout=BOUND_S) as answer:
            return answer.status, answer.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()
    except OSError as error:  # the server went away mid-request: the stop under test
        return 0, str(error).encode()


def test_sigterm_during_concurrent_saves_and_views_stops_the_server(
    small_job: Path, tmp_path: Path
) -> None:
    """Concurrent saves (each holds signals while it renames the job's copy) and views in
    flight, then SIGTERM: the process ends within a turn of its loop with 143 and one line
    naming the copy it replaced, every camera answered 200 in the copy."""
    stamp = tmp_path / "stamp"
    args = [sys.executable, str(DRIVER), "serve", "TERM", str(stamp), "view", str(small_job),
            "--port", "0", "-q"]  # fmt: skip
    with serving(args) as (process, url, _):
        names = [f"load_{i}" for i in range(8)]
        start = threading.Barrier(len(names))
        saved: dict[str, int] = {}

        def save(name: str) -> None:
            start.wait()
            saved[name] = fetch(url + f"api/camera?name={name}&origin=2,1,3", "POST")[0]

        savers = [threading.Thread(target=save, args=(name,)) for name in names]
        for thread in savers:
            thread.start()
        for thread in savers:
            thread.join()
        assert saved == dict.fromkeys(names, 200)
        viewing = threading.Barrier(5)
        views: list[int] = []

        def view(i: int) -> None:
            viewing.wait()
            views.append(fetch(url + f"api/view?origin={1 + i / 10},1,3&width=256&spp=16")[0])

        viewers = [threading.Thread(target=view, args=(i,)) for i in range(4)]
        for thread in viewers:
            thread.start()
        viewing.wait()  # the views are sent: some are traced while the signal comes
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=BOUND_S)
        for thread in viewers:
            thread.join()
    assert process.returncode == EXIT_TERMINATED, err
    turns = int(stamp.read_text()) if stamp.exists() else 0  # loop turns begun after the signal
    assert turns <= 1, turns
    copy = load_job(small_job).output / "job_view.yaml"
    assert err.strip().splitlines() == [
        f"sensaov: error: stopped by SIGTERM; replaced: {copy}; no other output was touched"
    ]
    assert set(names) <= {c.name for c in load_job(copy).inspection_cameras}
    assert all(code in (0, 200, 503) for code in views), views


def _memory(pid: int, field: str) -> int:
    """A field of /proc/PID/status in bytes (VmRSS now, VmHWM the peak since its reset)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no {field} in /proc/{pid}/status")


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux's /proc")
def test_the_memory_budget_holds_for_kept_passes_and_concurrent_views(small_job: Path) -> None:
    """Under SENSAOV_MEMORY_BUDGET, distinct views one after another (each pass kept for the
    pick that may follow) and six at once: the process's peak resident memory grows by no
    more than the budget above what it held when it began to serve; a view over the whole
    budget is refused in one line."""
    budget = 96 << 20
    env = {"SENSAOV_MEMORY_BUDGET": f"{budget >> 20}M"}
    with serving([sys.executable, "-m", "sensaov_cli", "view", str(small_job), "--port", "0",
                  "-q"], env) as (process, url, _):  # fmt: skip
        assert fetch(url + "api/view?width=16&spp=4")[0] == 200  # compiled; its pass is tiny
        base = _memory(process.pid, "VmRSS")
        Path(f"/proc/{process.pid}/clear_refs").write_text("5")  # VmHWM := VmRSS
        view = "api/view?width=384&spp=4&origin={},1,3"
        answers = [fetch(url + view.format(1 + i / 20))[0] for i in range(12)]
        start = threading.Barrier(6)

        def concurrent(i: int) -> None:
            start.wait()
            answers.append(fetch(url + view.format(-1 - i / 20))[0])

        threads = [threading.Thread(target=concurrent, args=(i,)) for i in range(6)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        peak = _memory(process.pid, "VmHWM")
        status, body = fetch(url + "api/view?width=2048&height=2048&spp=64")
    assert answers == [200] * 18
    assert peak - base <= budget, f"grew by {(peak - base) >> 20} MiB over {budget >> 20} MiB"
    assert status == 400 and b"over the memory budget of 96.0 MiB" in body
    assert body.count(b"\n") == 1


FAKE_BROWSER = """
import sys, urllib.request
url = sys.argv[1]
try:
    with urllib.request.urlopen(url + "api/meta", timeout=60) as answer:
        print("browser fetched", answer.status, answer.read()[:40].decode(), flush=True)
except OSError as error:
    print("browser failed", error, flush=True)
"""


def test_open_launches_the_browser_once_the_page_is_served(small_job: Path, tmp_path: Path) -> None:
    """--open with a browser that waits for its page (as a console browser does; here a
    script named by $BROWSER that fetches the URL): the page is served to it, the server keeps
    answering, and the browser's output arrives after the URL."""
    browser = tmp_path / "browser.py"
    browser.write_text(FAKE_BROWSER)
    env = {"BROWSER": f"{sys.executable} {browser} %s"}
    args = [sys.executable, "-m", "sensaov_cli", "view", str(small_job), "--port", "0", "-q",
            "--open"]  # fmt: skip
    with serving(args, env) as (process, url, lines):
        said = lines.get(timeout=BOUND_S)
        assert said.startswith('browser fetched 200 {"format": "sensaov-view"'), said
        assert fetch(url + "api/meta")[0] == 200
        process.send_signal(signal.SIGTERM)
        process.communicate(timeout=BOUND_S)
    assert process.returncode == EXIT_TERMINATED


def test_deferred_blocks_in_several_threads_leave_signals_raising(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Two threads in overlapping deferred blocks (concurrent saves), leaving in the other
    order than they entered: a stop after both still raises, one during either is recorded
    and raised at the end of the main thread's block, never lost."""
    monkeypatch.setattr(interrupts, "_signal", [])
    monkeypatch.setattr(interrupts, "_raising", [True])
    first_in, second_in, first_out = (threading.Event() for _ in range(3))

    def first() -> None:
        with interrupts.deferred():
            first_in.set()
            second_in.wait(BOUND_S)
        first_out.set()

    def second() -> None:
        first_in.wait(BOUND_S)
        with interrupts.deferred():
            second_in.set()
            first_out.wait(BOUND_S)

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    with pytest.raises(KeyboardInterrupt):
        interrupts._stop(signal.SIGTERM, None)
    monkeypatch.setattr(interrupts, "_signal", [])
    with pytest.raises(KeyboardInterrupt), interrupts.deferred():
        with interrupts.deferred():
            interrupts._stop(signal.SIGTERM, None)  # recorded only
        assert interrupts.requested()  # an inner block's end does not raise yet
    assert json.dumps(interrupts._signal) == json.dumps([int(signal.SIGTERM)])


def _pass(pixels: int) -> VisibilityPass:
    """A pass of ``pixels`` pixels (64 bytes each, kept arrays), for the ledger."""
    coverage = Coverage(np.arange(pixels, dtype=np.int64), np.zeros(pixels, np.int32),
                        np.ones(pixels, np.int32))  # fmt: skip
    ranks = np.zeros((1, pixels, 6), np.int32)
    return VisibilityPass(pixels, 1, 1, ("a",), None, coverage, ranks, ranks.astype(np.float32))


def test_the_ledger_drops_kept_passes_for_a_request_and_refuses_past_the_budget(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Kept passes give way to a request, oldest first; a request over the whole budget is a
    400 naming its setting; one that finds the budget held past the wait is a 503."""
    from sensaov_cli.errors import MemoryBudgetError
    from sensaov_cli.live import view_memory
    from sensaov_cli.live.view_memory import Busy, MemoryLedger, pass_bytes

    monkeypatch.setenv("SENSAOV_MEMORY_BUDGET", "100K")
    ledger = MemoryLedger()
    old, new = _pass(512), _pass(512)  # 32 KiB each
    assert pass_bytes(old) == 512 * 64
    ledger.keep("old", old)
    ledger.keep("new", new)
    assert ledger.kept("old") is old and ledger.kept("new") is new  # "new" now the newest
    with ledger.reserved(50 << 10, "small"):  # 100 KiB - 50 KiB: one pass must go, the oldest
        assert ledger.kept("old") is None and ledger.kept("new") is new
        monkeypatch.setattr(view_memory, "WAIT_S", 0.0)
        with pytest.raises(Busy, match="other views hold the memory budget") as busy:
            with ledger.reserved(60 << 10, "second"):
                pass
        assert busy.value.status == 503
    with pytest.raises(MemoryBudgetError, match="huge: .* over the memory budget of 100.0 KiB"):
        with ledger.reserved(200 << 10, "huge"):
            pass
    ledger.keep("again", _pass(512))
    assert ledger.kept_bytes == 512 * 64
    with ledger.reserved(90 << 10, "alone"):  # the kept pass gives way, nothing waits
        assert ledger.kept_bytes == 0


def test_a_stop_during_a_save_names_the_copy_it_replaced(small_job: Path, tmp_path: Path) -> None:
    """SIGTERM lands while a save renames the job's copy (signals held in that thread, so the
    handler only records it): the server still stops, after the rename, and its line names the
    copy, which holds the camera."""
    copy = load_job(small_job).output / "job_view.yaml"
    copy.unlink(missing_ok=True)
    args = [sys.executable, str(DRIVER), "rename", "TERM", str(tmp_path / "stamp"), "view",
            str(small_job), "--port", "0", "-q"]  # fmt: skip
    with serving(args) as (process, url, _):
        saver = threading.Thread(target=fetch, args=(url + "api/camera?name=last", "POST"))
        saver.start()
        _, err = process.communicate(timeout=BOUND_S)
        saver.join()
    assert process.returncode == EXIT_TERMINATED, err
    assert err.strip().splitlines() == [
        f"sensaov: error: stopped by SIGTERM; replaced: {copy}; no other output was touched"
    ]
    assert "last" in {c.name for c in load_job(copy).inspection_cameras}
