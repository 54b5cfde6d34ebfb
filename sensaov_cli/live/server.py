"""The HTTP face of ``sensaov view``: the standard library's threading server, routing only.

One user on the loopback address needs no web framework. Every answer is computed by
:class:`~sensaov_cli.live.session.ViewSession`; here requests are routed, a bad value becomes
HTTP 400 with a one-line reason, and two browser-borne attacks on a local server are refused:
a page of another site reaching it by DNS rebinding (the Host header must name this server)
and a cross-site form posting to it (a save must carry the ``X-Sensaov`` header, which no form
can set). The server stops when the main thread is interrupted (Ctrl-C, SIGTERM).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from sensaov_cli.errors import SensaovError, ServerError
from sensaov_cli.live.page import page_html
from sensaov_cli.live.query import VIEW_KEYS, single_values
from sensaov_cli.live.save import save_viewpoint, viewpoint_yaml
from sensaov_cli.live.session import Answer, ViewSession
from sensaov_cli.pipeline.run import FORWARD_NAME

LOOPBACK = ("127.0.0.1", "localhost", "::1", "[::1]")
SAVE_HEADER = "X-Sensaov"
CAMERA_KEYS = (*VIEW_KEYS, "name")


class ViewServer(ThreadingHTTPServer):
    daemon_threads = True  # a request in flight never holds the process open after a stop

    def __init__(
        self,
        address: tuple[str, int],
        on_save: Callable[[str], None],
        log: Callable[[str], None] | None,
    ):
        self.on_save, self.log = on_save, log
        self._session: ViewSession | None = None
        self.inputs: tuple[Path, ...] = ()
        super().__init__(address, _Handler)

    @property
    def session(self) -> ViewSession:
        if self._session is None:
            raise RuntimeError("the server answers once a session is attached")
        return self._session

    def attach(self, session: ViewSession) -> None:
        """Answer from ``session`` (the server listens before the scene loads: a taken port
        is reported at once, not after the load)."""
        self._session = session
        buffer = session.buffer_path  # a saved camera never replaces the buffer or its sidecar
        self.inputs = (
            *session.job.input_files(),
            *session.loaded.prepared.files,
            buffer,
            buffer.with_name(FORWARD_NAME),
        )

    @property
    def url(self) -> str:
        host, port = str(self.server_address[0]), self.server_address[1]
        shown = f"[{host}]" if ":" in host else host
        return f"http://{shown}:{port}/"

    def host_allowed(self, header: str | None) -> bool:
        """Whether a request's Host header names this server (DNS rebinding defence)."""
        host, port = str(self.server_address[0]), self.server_address[1]
        if host not in LOOPBACK:  # bound to a public address on purpose: any name may reach it
            return True
        allowed = {f"{name}:{port}" for name in LOOPBACK}
        return header is not None and header.lower() in allowed


class _Handler(BaseHTTPRequestHandler):
    server: ViewServer
    protocol_version = "HTTP/1.1"

    def do_GET(self) -> None:  # noqa: N802 - the standard library's name
        self._answer(self._get)

    def do_POST(self) -> None:  # noqa: N802
        self._answer(self._post)

    def _get(self, path: str, query: dict[str, list[str]]) -> Answer:
        session = self.server.session
        if path == "/":
            return Answer(page_html().encode(), "text/html; charset=utf-8")
        if path == "/api/meta":
            return _json(session.meta())
        if path == "/api/view":
            return session.view(query)
        if path == "/api/pick":
            return _json(session.pick(query))
        if path == "/api/sunburst":
            return _json(session.sunburst(query))
        if path == "/api/camera":
            values = single_values(query, CAMERA_KEYS)
            request = session.request(values)
            return _json({"yaml": viewpoint_yaml(request, values.get("name", "view_1"))})
        return Answer(f"no such page: {path}\n".encode(), "text/plain", {"status": "404"})

    def _post(self, path: str, query: dict[str, list[str]]) -> Answer:
        if path != "/api/camera":
            return Answer(f"no such page: {path}\n".encode(), "text/plain", {"status": "404"})
        if self.headers.get(SAVE_HEADER) is None:
            return _refuse(403, f"a save must carry the {SAVE_HEADER} header")
        session = self.server.session
        values = single_values(query, CAMERA_KEYS)
        if "name" not in values:
            return _refuse(400, "a saved camera needs a name")
        request = session.request(values)
        copy = save_viewpoint(
            session.job, request, values["name"], session.buffer_path, self.server.inputs
        )
        text = viewpoint_yaml(request, values["name"])
        self.server.on_save(text)
        return _json({"path": str(copy), "yaml": text})

    def _answer(self, route: Callable[[str, dict[str, list[str]]], Answer]) -> None:
        if not self.server.host_allowed(self.headers.get("Host")):
            answer = _refuse(403, "this server answers only requests addressed to it by name")
        else:
            parts = urlsplit(self.path)
            try:
                answer = route(parts.path, parse_qs(parts.query, keep_blank_values=True))
            except SensaovError as error:  # a bad value: one line, never a traceback
                answer = _refuse(400, str(error))
            except Exception as error:  # noqa: BLE001 - the server outlives a failed request
                answer = _refuse(500, f"internal error: {type(error).__name__}: {error}")
        self._send(answer)

    def _send(self, answer: Answer) -> None:
        headers = dict(answer.headers)
        status = int(headers.pop("status", "200"))
        self.send_response(status)
        self.send_header("Content-Type", answer.content_type)
        self.send_header("Content-Length", str(len(answer.body)))
        self.send_header("Cache-Control", "no-store")
        for key, value in headers.items():
            self.send_header(key, value)
        self.end_headers()
        self.wfile.write(answer.body)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the stdlib's name
        if self.server.log is not None:
            self.server.log(format % args)


def _json(data: Any) -> Answer:
    return Answer(json.dumps(data, allow_nan=False).encode(), "application/json")


def _refuse(status: int, reason: str) -> Answer:
    line = " ".join(reason.split()) + "\n"
    return Answer(line.encode(), "text/plain; charset=utf-8", {"status": str(status)})


def listen(
    host: str,
    port: int,
    *,
    on_save: Callable[[str], None],
    log: Callable[[str], None] | None = None,
) -> ViewServer:
    """Bind ``host:port`` (0: any free port) or say why not; requests wait for :func:`serve`."""
    try:
        return ViewServer((host, port), on_save, log)
    except OSError as error:
        raise ServerError(
            f"cannot listen on {host}:{port}: {error.strerror or error}",
            hint="choose another --port (0 picks a free one)",
        ) from None


def serve(server: ViewServer, session: ViewSession, *, ready: Callable[[str], None]) -> None:
    """Answer from ``session`` until the main thread is interrupted; ``ready`` gets the URL."""
    server.attach(session)
    try:
        ready(server.url)
        server.serve_forever(poll_interval=0.2)
    finally:
        server.server_close()
