"""The HTTP face of ``sensaov view``: the interface of docs/view.md, its page, its saved cameras.

One user on the loopback address needs no web framework: the standard library's threading
server suffices; a bad value becomes HTTP 400 with a one-line reason. Refused: a page of another
site reaching the server by DNS rebinding (the Host header must name it) and a cross-site form
posting to it (a save must carry the ``X-Sensaov`` header, which no form can set). The page
draws its colour bar and sunburst with the previews' colour table, filled in here, so legend
and picture cannot disagree. A saved viewpoint is appended to ``<output>/<job stem>_view.yaml``
(validated as a job before it replaces anything); nothing is written anywhere else.
"""

from __future__ import annotations

import errno
import ipaddress
import json
import socket
import sys
import threading
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from functools import cache, partial
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from sensaov_cli import interrupts
from sensaov_cli.errors import RequestError, SensaovError, ServerError, SpecError
from sensaov_cli.job.load import (
    camera_names,
    camera_yaml,
    check_camera_name,
    job_copy_text,
    load_job,
)
from sensaov_cli.job.spec import CameraSpec, JobSpec
from sensaov_cli.live.legend_words import legend_words
from sensaov_cli.live.session import (
    CAMERA_KEYS,
    PICK_KEYS,
    REST_SPP,
    SUNBURST_KEYS,
    VIEW_KEYS,
    Pick,
    Picture,
    ViewRequest,
    ViewSession,
    pick_request,
    single_values,
)
from sensaov_cli.live.view_memory import Busy
from sensaov_cli.outputs.atomic import atomic_write, check_writable, made_by, refuse_unsafe_outputs
from sensaov_cli.outputs.previews import RDBU
from sensaov_cli.outputs.sunburst_drawing import wedge_caption
from sensaov_cli.pipeline.run import FORWARD_NAME
from sensaov_cli.views.hierarchy import Panel

META_FORMAT = "sensaov-view"
META_VERSION = 1
LOCALHOST = ("127.0.0.1", "::1")  # the addresses the name "localhost" reaches
SAVE_HEADER = "X-Sensaov"
SAVED_VIS_SPP = 16  # project's default for an inspection camera
_TABLE_MARK = "/*RDBU*/[]"
PAGE_LABEL_CHARS = 12  # of a wedge's label on the page's sunburst


@dataclass(frozen=True)
class Answer:
    body: bytes
    content_type: str
    headers: dict[str, str] = field(default_factory=dict)
    status: int = 200


class ViewServer(ThreadingHTTPServer):
    daemon_threads = True  # a request in flight never holds the process open after a stop

    session: ViewSession  # attached before the first request is accepted (:func:`serve`)

    def __init__(
        self,
        address: tuple[str, int],
        on_save: Callable[[str], None],
        log: Callable[[str], None] | None,
    ):
        self.on_save, self.log = on_save, log
        # Saves read the job's copy, append, and replace it: one at a time, or concurrent
        # saves each append to the same old copy and all but the last camera are lost.
        self.save_lock = threading.Lock()
        self.serving = threading.Event()  # set once the loop answers (--open waits for it)
        self.address_family = _family(address[0])  # an IPv6 address binds an IPv6 socket
        super().__init__(address, _Handler)

    def serve_forever(self, poll_interval: float = 0.5) -> None:
        self.serving.set()  # from here on, a connection waiting in the backlog is answered
        super().serve_forever(poll_interval)

    def service_actions(self) -> None:
        """Each turn of the loop: a stop that was only recorded (it came while a request's
        thread held signals for a save) ends the loop here, in the main thread."""
        super().service_actions()
        interrupts.raise_if_stopped()

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A connection that failed outside a request's answer (a client gone while its request
        was read): one line under --log, never a traceback."""
        if self.log is not None:
            error = sys.exc_info()[1]
            self.log(_printable(f"{client_address[0]}: connection dropped ({error!r})"))

    def echo_saved(self, text: str) -> None:
        """Print a saved camera's YAML on stdout: a courtesy; the save stands when stdout is
        gone (its reader closed the pipe), and the page is told it succeeded."""
        try:
            self.on_save(text)
        except (OSError, ValueError) as error:
            if self.log is not None:
                self.log(f"the saved camera was not printed on stdout: {error}")

    def attach(self, session: ViewSession) -> None:
        """Answer from ``session`` (the server listens before the scene loads: a taken port
        is reported at once, not after the load)."""
        self.session = session

    @property
    def url(self) -> str:
        host, port = str(self.server_address[0]), self.server_address[1]
        shown = f"[{host}]" if ":" in host else host
        return f"http://{shown}:{port}/"

    def host_allowed(self, header: str | None) -> bool:
        """Whether a request's Host header names this server (DNS rebinding defence): on a
        loopback address, the address itself, or ``localhost`` where that name leads here."""
        host, port = str(self.server_address[0]), self.server_address[1]
        if not ipaddress.ip_address(host).is_loopback:  # a public address on purpose: any name
            return True
        names = [f"[{host}]" if ":" in host else host]
        if host in LOCALHOST:
            names.append("localhost")
        allowed = {f"{name}:{port}" for name in names}
        if port == 80:  # a browser leaves the default port out
            allowed.update(names)
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
            return _meta(session)
        if path == "/api/view":
            return _picture(session.view(session.request(single_values(query, VIEW_KEYS))))
        if path == "/api/pick":
            values = single_values(query, PICK_KEYS)
            return _pick(session.pick(pick_request(session.request(values), values)))
        if path == "/api/sunburst":
            objective = single_values(query, SUNBURST_KEYS).get("objective")
            return _sunburst(session.sunburst(objective))
        if path == "/api/camera":
            values = single_values(query, CAMERA_KEYS)
            request = session.request(values)
            return _json({"yaml": viewpoint_yaml(request, values.get("name", "view_1"))})
        return _missing(path)

    def _post(self, path: str, query: dict[str, list[str]]) -> Answer:
        if path != "/api/camera":
            return _missing(path)
        if self.headers.get(SAVE_HEADER) is None:
            return _refuse(403, f"a save must carry the {SAVE_HEADER} header")
        session = self.server.session
        values = single_values(query, CAMERA_KEYS)
        if "name" not in values:
            return _refuse(400, "a saved camera needs a name")
        request = session.request(values)
        with self.server.save_lock:
            copy = save_viewpoint(session, request, values["name"])
            text = viewpoint_yaml(request, values["name"])
            self.server.echo_saved(text)
        return _json({"path": str(copy), "yaml": text})

    def _answer(self, route: Callable[[str, dict[str, list[str]]], Answer]) -> None:
        if not self.server.host_allowed(self.headers.get("Host")):
            answer = _refuse(403, "this server answers only requests addressed to it by name")
        else:
            parts = urlsplit(self.path)
            try:
                answer = route(parts.path, parse_qs(parts.query, keep_blank_values=True))
            except SensaovError as error:  # a bad value: one line, never a traceback
                answer = _refuse(error.status if isinstance(error, Busy) else 400, str(error))
            except KeyboardInterrupt:  # a stop came while this request traced: the main
                answer = _refuse(503, "the server is stopping")  # thread ends the process
            except Exception as error:  # noqa: BLE001 - the server outlives a failed request
                answer = _refuse(500, f"internal error: {type(error).__name__}: {error}")
        self._send(answer)

    def _send(self, answer: Answer) -> None:
        try:
            self.send_response(answer.status)
            self.send_header("Content-Type", answer.content_type)
            self.send_header("Content-Length", str(len(answer.body)))
            self.send_header("Cache-Control", "no-store")
            for key, value in answer.headers.items():
                self.send_header(key, value)
            self.end_headers()
            self.wfile.write(answer.body)
            self.wfile.flush()
        except OSError as error:  # the client went away before its answer: nothing to tell it
            self.close_connection = True
            self.log_message("%s: the client left before its answer (%s)", self.path, error)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the stdlib's name
        if self.server.log is not None:
            self.server.log(_printable(format % args))


def _printable(text: str) -> str:
    """``text`` with control characters escaped: a request line is a stranger's bytes, and
    raw escape codes on a terminal could rewrite what it shows."""
    return "".join(
        c if c.isprintable() or c == " " else c.encode("unicode_escape").decode("ascii")
        for c in text
    )


def _family(host: str) -> socket.AddressFamily:
    """The socket family of the address ``host`` names (IPv4 for a name that resolves to both)."""
    try:
        return socket.AF_INET6 if ipaddress.ip_address(host).version == 6 else socket.AF_INET
    except ValueError:  # a name: what it resolves to
        pass
    try:
        found = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except OSError as error:
        raise ServerError(
            f"cannot listen on {host}: the name does not resolve ({error.strerror or error})",
            hint="give --host an address, e.g. 127.0.0.1 or ::1",
        ) from None
    families = [entry[0] for entry in found]
    return socket.AF_INET if socket.AF_INET in families else families[0]


@cache
def page_html() -> str:
    """The page's text, with the colour table filled in."""
    text = resources.files("sensaov_cli.live").joinpath("page.html").read_text("utf-8")
    if _TABLE_MARK not in text:
        raise RuntimeError("page.html lost its colour table mark")
    return text.replace(_TABLE_MARK, json.dumps(RDBU.tolist()))


def _meta(session: ViewSession) -> Answer:
    """What the page needs first: the buffer's names, the channels, the cameras, the defaults."""
    buffer, first = session.buffer, session.objective_camera
    cameras = [
        {"name": c.name, "origin": c.pose.look_at.origin, "target": c.pose.look_at.target,
         "up": c.pose.look_at.up, "fov": c.pose.fov, "width": c.size[0], "height": c.size[1],
         "note": c.pose.note}
        for c in session.cameras
    ]  # fmt: skip
    return _json({
        "format": META_FORMAT,
        "format_version": META_VERSION,
        "job": str(session.job.path),
        "buffer": str(session.buffer_path),
        "buffer_id": session.buffer_id,
        "objectives": [o.name for o in buffer.objectives],
        "objective_values": {o.name: o.value for o in buffer.objectives},
        "channels": session.sources.names(),
        "objective_camera_only": session.sources.objective_only(),
        "cameras": cameras,
        "bounds": {"min": session.bounds[0], "max": session.bounds[1]},
        "objects": buffer.objects,
        "materials": {o: session.material(o) for o in buffer.objects},
        "defaults": {"width": first.size[0], "height": first.size[1], "spp": 1,
                     "rest_spp": REST_SPP},
        "made_by": made_by("view"),
    })  # fmt: skip


def _picture(picture: Picture) -> Answer:
    """A view's bytes; its legend, size and cost in headers (the page reads them)."""
    legend = {**asdict(picture.legend), "said": legend_words(picture.legend)}
    headers = {
        "X-Sensaov-Legend": json.dumps(legend, ensure_ascii=True),
        "X-Sensaov-Size": f"{picture.size[0]}x{picture.size[1]}",
        "X-Sensaov-Ms": f"{picture.ms:.1f}",
    }
    return Answer(picture.body, picture.content_type, headers)


def _pick(pick: Pick) -> Answer:
    """A pick's JSON: a pixel's fields for a click on a pixel, the object's once there is one."""
    body: dict[str, Any] = {"objective": pick.objective, "channel": pick.channel}
    pixel = pick.pixel
    if pixel is not None:
        body.update(x=pixel.x, y=pixel.y)
    body.update(object=pick.object, material=pick.material)
    if pixel is not None:
        body.update(
            coverage=[{"object": name, "coverage": share} for name, share in pixel.coverage],
            position=pixel.position,
            distance=pixel.distance,
            value=pixel.value,
        )
    summary = pick.summary
    if summary is not None:
        rows = [asdict(row) for row in summary.parameters]
        body.update(weight=summary.weight, parameters=rows, trust=summary.trust)
        if summary.rank is not None:
            body.update(asdict(summary.rank))
    return _json(body)


def _sunburst(panel: Panel) -> Answer:
    return _json({
        "objective": panel.objective,
        "value": panel.value,
        "wedges": [{**asdict(w), "caption": wedge_caption(w, PAGE_LABEL_CHARS)}
                   for w in panel.wedges],  # fmt: skip
        "no_gradient": panel.no_gradient,
    })  # fmt: skip


def _json(data: object) -> Answer:
    return Answer(json.dumps(data, allow_nan=False).encode(), "application/json")


def _refuse(status: int, reason: str) -> Answer:
    line = " ".join(reason.split()) + "\n"
    return Answer(line.encode(), "text/plain; charset=utf-8", status=status)


def _missing(path: str) -> Answer:
    return Answer(f"no such page: {path}\n".encode(), "text/plain", status=404)


def viewpoint_camera(request: ViewRequest, name: str) -> CameraSpec:
    return CameraSpec(
        name,
        look_at=request.pose.look_at,
        fov=request.pose.fov,
        resolution=(request.width, request.height),
        vis_spp=SAVED_VIS_SPP,
    )


def viewpoint_yaml(request: ViewRequest, name: str) -> str:
    return camera_yaml(viewpoint_camera(request, name))


def copy_path(job: JobSpec) -> Path:
    return job.output / f"{job.path.stem}_view.yaml"


def save_viewpoint(session: ViewSession, request: ViewRequest, name: str) -> Path:
    """Append the request's camera, named ``name``, to the job's copy; returns the copy."""
    job, buffer = session.job, session.buffer_path
    copy = copy_path(job)
    # Before the copy is read as the base of the next save: a copy that is a link to the
    # buffer (or its sidecar) or a scene file, or a FIFO, is refused, never parsed or waited on.
    inputs = (*job.input_files(), *session.loaded.prepared.files, buffer,
              buffer.with_name(FORWARD_NAME))  # fmt: skip
    refuse_unsafe_outputs(inputs, [copy], where=str(job.path))
    check_writable(job.output, [copy.name])
    base = copy if copy.is_file() else job.path
    if base == copy:  # a copy edited since into no job at all: refused at its line, not parsed
        load_job(copy)
    problem = check_camera_name(name, camera_names(base))
    if problem is not None:
        raise RequestError(problem, hint="choose another name")
    text = job_copy_text(job, base, [viewpoint_camera(request, name)], copy, buffer)

    def write(tmp: Path) -> None:
        tmp.write_text(text)
        try:
            load_job(tmp)  # a copy that is not a valid job never replaces anything
        except SpecError as error:  # said of the copy: the temporary is gone when it is read
            named = partial(_renamed, str(tmp), str(copy))
            where = named(error.where) if error.where else None
            raise SpecError(named(error.message), where=where, hint=error.hint) from None

    atomic_write(copy, write)
    return copy


def _renamed(old: str, new: str, text: str) -> str:
    return text.replace(old, new)


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
        shown = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        port_problem = error.errno in (errno.EADDRINUSE, errno.EACCES)
        raise ServerError(
            f"cannot listen on {shown}: {error.strerror or error}",
            hint="choose another --port (0 picks a free one)"
            if port_problem
            else "choose another --host: an address of this machine (127.0.0.1 or ::1)",
        ) from None


def serve(
    server: ViewServer,
    session: ViewSession,
    *,
    ready: Callable[[str], None],
    open_page: Callable[[str], None] | None = None,
) -> None:
    """Answer from ``session`` until the main thread is interrupted; ``ready`` gets the URL;
    ``open_page`` (a browser) gets it once the loop answers, from a thread of its own (a
    console browser that waits for its page to load must not wait on this loop)."""
    server.attach(session)
    try:
        ready(server.url)
        if open_page is not None:
            opener = partial(_open_when_serving, server, open_page)
            threading.Thread(target=opener, name="open-page", daemon=True).start()
        server.serve_forever(poll_interval=0.2)
    finally:
        # A stop waits for a save in flight to rename or drop the job's copy (milliseconds), so
        # that the line saying what was replaced is true of the disk when it is printed.
        with server.save_lock:
            server.server_close()


def _open_when_serving(server: ViewServer, open_page: Callable[[str], None]) -> None:
    server.serving.wait()
    open_page(server.url)
