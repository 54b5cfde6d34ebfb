"""A minimal W3C WebDriver client (urllib only) for driving headless Chromium in tests.

Debian's ``chromium-driver`` speaks the W3C protocol over HTTP; these few calls (a session,
navigation, script, pointer actions, screenshots) are all the page tests need, so no browser
automation package is installed for them.
"""

from __future__ import annotations

import base64
import json
import shutil
import socket
import subprocess
import time
import urllib.request
from pathlib import Path
from typing import Any

ELEMENT = "element-6066-11e4-a52e-4f735466cecf"


def browser_missing() -> str | None:
    """Why the browser tests cannot run here, or None when they can."""
    for tool in ("chromium", "chromedriver"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (Debian: apt-get install chromium chromium-driver)"
    return None


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


class Browser:
    """One headless Chromium session through chromedriver."""

    def __init__(self, width: int = 1400, height: int = 1000):
        self.port = free_port()
        self.driver = subprocess.Popen(
            ["chromedriver", f"--port={self.port}"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        self.base = f"http://127.0.0.1:{self.port}"
        self._wait_for_driver()
        options = {
            "binary": shutil.which("chromium"),
            "args": ["--headless=new", "--no-sandbox", "--disable-gpu",
                     f"--window-size={width},{height}"],
        }  # fmt: skip
        caps = {"capabilities": {"alwaysMatch": {"goog:chromeOptions": options}}}
        self.session = self._call("POST", "/session", caps)["sessionId"]

    def _wait_for_driver(self) -> None:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            try:
                urllib.request.urlopen(self.base + "/status", timeout=1).read()
                return
            except OSError:
                time.sleep(0.1)
        raise RuntimeError("chromedriver did not start")

    def _call(self, method: str, path: str, body: dict[str, Any] | None = None) -> Any:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(self.base + path, data=data, method=method)
        request.add_header("Content-Type", "application/json")
        with urllib.request.urlopen(request, timeout=60) as answer:
            return json.loads(answer.read())["value"]

    def _session(self, method: str, path: str, body: dict[str, Any] | None = None) -> Any:
        return self._call(method, f"/session/{self.session}{path}", body)

    def get(self, url: str) -> None:
        self._session("POST", "/url", {"url": url})

    def script(self, source: str, *args: Any) -> Any:
        return self._session("POST", "/execute/sync", {"script": source, "args": list(args)})

    def wait_for(self, source: str, timeout: float = 30.0) -> Any:
        """Poll ``source`` (a script returning a value) until it is truthy; return it."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = self.script(source)
            if value:
                return value
            time.sleep(0.1)
        raise TimeoutError(f"the page never satisfied: {source}")

    def element(self, css: str) -> dict[str, str]:
        return dict(self._session("POST", "/element", {"using": "css selector", "value": css}))

    def drag(
        self, css: str, start: tuple[int, int], moves: list[tuple[int, int]], step_ms: int = 30
    ) -> None:
        """Press the left button at ``start`` (from the element's centre) and move by each
        step of ``moves`` in turn, ``step_ms`` each, then release."""
        origin = self.element(css)
        actions: list[dict[str, Any]] = [
            {"type": "pointerMove", "origin": origin, "x": start[0], "y": start[1]},
            {"type": "pointerDown", "button": 0},
            *self._steps(origin, start, moves, step_ms),
            {"type": "pointerUp", "button": 0},
        ]
        self._perform(actions)

    def hover(
        self, css: str, start: tuple[int, int], moves: list[tuple[int, int]], step_ms: int = 30
    ) -> None:
        """Move the pointer, no button pressed, from ``start`` by each step of ``moves``."""
        origin = self.element(css)
        first = {"type": "pointerMove", "origin": origin, "x": start[0], "y": start[1]}
        self._perform([first, *self._steps(origin, start, moves, step_ms)])

    @staticmethod
    def _steps(
        origin: dict[str, str], start: tuple[int, int], moves: list[tuple[int, int]], ms: int
    ) -> list[dict[str, Any]]:
        steps: list[dict[str, Any]] = []
        x, y = start
        for dx, dy in moves:
            x, y = x + dx, y + dy
            steps.append({"type": "pointerMove", "origin": origin, "x": x, "y": y, "duration": ms})
        return steps

    def click(self, css: str, at: tuple[int, int]) -> None:
        origin = self.element(css)
        self._perform([
            {"type": "pointerMove", "origin": origin, "x": at[0], "y": at[1]},
            {"type": "pointerDown", "button": 0},
            {"type": "pointerUp", "button": 0},
        ])  # fmt: skip

    def _perform(self, actions: list[dict[str, Any]]) -> None:
        pointer = {"type": "pointer", "id": "mouse", "parameters": {"pointerType": "mouse"},
                   "actions": actions}  # fmt: skip
        self._session("POST", "/actions", {"actions": [pointer]})

    def screenshot(self, path: Path) -> None:
        path.write_bytes(base64.b64decode(self._session("GET", "/screenshot")))

    def close(self) -> None:
        try:
            self._session("DELETE", "")
        finally:
            self.driver.terminate()
            self.driver.wait(timeout=10)
