"""``sensaov view``: the HTTP interface, the free camera, the page.

One buffer of the demo job (configs/cbox.yaml, made small: 24x24 at 4 spp, its forward layers
kept) serves every test. The acceptance test runs the real command in a process of its own and
stops it with SIGTERM; the others talk to one in-process server. The page test drives headless
Chromium and skips, saying why, where Chromium or its driver is absent.
"""

from __future__ import annotations

import http.client
import io
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.buffer.queries import per_object
from sensaov_cli.errors import (
    EXIT_BAD_INPUT,
    EXIT_HANGUP,
    EXIT_INTERRUPTED,
    EXIT_TERMINATED,
    RequestError,
)
from sensaov_cli.job.load import load_job
from sensaov_cli.job.spec import LookAt
from sensaov_cli.live.server import ViewServer, copy_path
from sensaov_cli.live.session import ViewSession, open_session, single_values, view_request
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.progress import Progress
from sensaov_cli.render.visibility import Pose, ViewTracer, sensor_pose
from sensaov_cli.views.channels import ChannelValues
from sensaov_cli.views.hierarchy import is_trusted

from .conftest import ROOT, sensaov
from .webdriver import Browser, browser_missing, free_port

CBOX = ROOT / "configs" / "cbox.yaml"
DRIVER = Path(__file__).with_name("signal_driver.py")
SHOTS = os.environ.get("SENSAOV_SHOTS")  # a folder to keep the page test's screenshots in


@pytest.fixture(scope="module")
def small_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """configs/cbox.yaml at 24x24 and 4 spp, written elsewhere, with its buffer made."""
    folder = tmp_path_factory.mktemp("view")
    data = yaml.safe_load(CBOX.read_text())
    data["scene"] = str(ROOT / "scenes" / "cbox" / "scene.xml")
    data["variant"] = "llvm_ad_rgb"
    # one batch: these tests look at the server and its pictures; errors and resolution in the
    # view are test_resolution's and test_default_errors' subject
    data["render"].update(spp=4, resolution=[24, 24], batches=1)
    data["repair"] = {"budget": 0}  # the biased gradients stay biased: the view leaves them out
    data["output"] = str(folder / "out")
    job = folder / "job.yaml"
    job.write_text(yaml.safe_dump(data, sort_keys=False))
    result = sensaov("run", "-q", str(job))
    assert result.returncode == 0, result.stderr
    return job


@pytest.fixture(scope="module")
def session(small_job: Path) -> ViewSession:
    job = load_job(small_job)
    return open_session(
        job, buffer_path=job.output / "buffer.npz", force=False, progress=Progress(quiet=True)
    )


@pytest.fixture(scope="module")
def server(session: ViewSession) -> Iterator[ViewServer]:
    saved: list[str] = []
    running = ViewServer(("127.0.0.1", 0), saved.append, None)
    running.attach(session)
    thread = threading.Thread(target=running.serve_forever, kwargs={"poll_interval": 0.05})
    thread.start()
    yield running
    running.shutdown()
    running.server_close()
    thread.join()


def get(url: str, headers: dict[str, str] | None = None, method: str = "GET") -> tuple:
    """(status, headers, body) of a request; HTTP errors are answers too."""
    request = urllib.request.Request(url, headers=headers or {}, method=method)
    try:
        with urllib.request.urlopen(request, timeout=60) as answer:
            return answer.status, dict(answer.headers), answer.read()
    except urllib.error.HTTPError as error:
        return error.code, dict(error.headers), error.read()


def png_pixels(data: bytes) -> np.ndarray:
    """Decode the 8-bit RGB PNGs the server writes."""
    from PIL import Image

    with Image.open(io.BytesIO(data), formats=["PNG"]) as image:
        assert image.mode == "RGB"
        return np.asarray(image)


def project_point(camera: dict[str, Any], point: tuple[float, float, float]) -> tuple[int, int]:
    """The pixel of a pinhole camera (``fov`` horizontal, as Mitsuba's look_at) that sees
    ``point``, computed here independently of the server's ray code."""
    origin, target, up = (np.array(camera[k], float) for k in ("origin", "target", "up"))
    forward = (target - origin) / np.linalg.norm(target - origin)
    left = np.cross(up, forward)
    left /= np.linalg.norm(left)
    true_up = np.cross(forward, left)
    d = np.array(point) - origin
    tan_x = math.tan(math.radians(camera["fov"]) / 2)
    tan_y = tan_x * camera["height"] / camera["width"]
    sx = -np.dot(d, left) / np.dot(d, forward) / tan_x
    sy = np.dot(d, true_up) / np.dot(d, forward) / tan_y
    return int((sx + 1) / 2 * camera["width"]), int((1 - sy) / 2 * camera["height"])


def test_view_command_serves_meta_two_views_and_a_pick_then_stops(small_job: Path) -> None:
    """The acceptance test: the real command on the demo job (made small: its buffer belongs to
    that version of the job, which `view` checks), as a user starts it."""
    buffer = load_job(small_job).output / "buffer.npz"
    port = free_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "sensaov_cli", "view", str(small_job), "--buffer", str(buffer),
         "--port", str(port)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert process.stdout is not None
        url = process.stdout.readline().strip()
        assert url == f"http://127.0.0.1:{port}/", process.stderr.read() if process.stderr else ""
        status, _, body = get(url + "api/meta")
        meta = json.loads(body)
        assert status == 200 and meta["objectives"] == ["mean_luma", "back_wall_luma"]
        assert meta["channels"][0] == "objects" and "walls" in meta["channels"]
        assert [c["name"] for c in meta["cameras"]] == ["objective", "overhead"]
        assert meta["bounds"]["max"] == [1.0, 1.0, 1.0] and len(meta["buffer_id"]) == 16
        views = []
        for origin in ("0,0,3.9", "2.5,1,2.5"):
            status, headers, body = get(url + f"api/view?channel=objects&origin={origin}&spp=4")
            assert status == 200 and headers["Content-Type"] == "image/png"
            views.append(png_pixels(body))
        assert views[0].shape == views[1].shape == (256, 256, 3)
        assert np.mean(np.any(views[0] != views[1], axis=2)) > 0.2  # other viewpoint, other image
        objective = {**meta["cameras"][0], "width": 256, "height": 256}
        x, y = project_point(objective, (0.3, 0.6, -1.0))  # a point on the back wall
        status, _, body = get(url + f"api/pick?x={x}&y={y}")
        pick = json.loads(body)
        assert status == 200 and pick["object"] == "back_wall", pick
        assert pick["position"][2] == pytest.approx(-1.0, abs=1e-3)
        assert [p["key"] for p in pick["parameters"]] == ["back_wall.bsdf.reflectance.value"]
        process.send_signal(signal.SIGTERM)  # how soon: test_a_signal_stops_the_server
        _, err = process.communicate(timeout=30)
        assert process.returncode == EXIT_TERMINATED
        assert err.strip().splitlines()[-1] == (
            "sensaov: error: stopped by SIGTERM; no output was replaced"
        )
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


@pytest.mark.parametrize(
    ("sig", "code"),
    [
        (signal.SIGTERM, EXIT_TERMINATED),
        (signal.SIGINT, EXIT_INTERRUPTED),
        (signal.SIGHUP, EXIT_HANGUP),
    ],
)
def test_a_signal_stops_the_server(
    small_job: Path, tmp_path: Path, sig: signal.Signals, code: int
) -> None:
    """SIGTERM from a farm, Ctrl-C, a closed terminal: the waiting server stops within the
    poll-loop turn the signal came in (counted in the process by signal_driver.py)."""
    stamp = tmp_path / "stamp"
    process = subprocess.Popen(
        [sys.executable, str(DRIVER), "serve", "TERM", str(stamp),
         "view", str(small_job), "--port", "0", "-q"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    assert process.stdout is not None
    url = process.stdout.readline().strip()
    assert get(url + "api/meta")[0] == 200
    process.send_signal(sig)
    _, err = process.communicate(timeout=30)
    assert process.returncode == code
    turns = int(stamp.read_text()) if stamp.exists() else 0  # poll-loop turns after the signal
    assert turns <= 1, turns
    line = f"sensaov: error: stopped by {sig.name}; no output was replaced"
    assert err.strip().splitlines() == [line]


def test_a_taken_port_and_a_missing_buffer_are_one_line_of_bad_input(
    small_job: Path, tmp_path: Path
) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = sensaov("view", str(small_job), "--port", str(port))
    assert result.returncode == EXIT_BAD_INPUT and result.stdout == ""
    assert result.stderr.splitlines() == [
        f"sensaov: error: cannot listen on 127.0.0.1:{port}: Address already in use (choose "
        "another --port (0 picks a free one)); no output was replaced"
    ]
    missing = tmp_path / "none.npz"
    result = sensaov("view", str(small_job), "--port", "0", "--buffer", str(missing))
    assert result.returncode == EXIT_BAD_INPUT
    assert len(result.stderr.splitlines()) == 1 and str(missing) in result.stderr


def test_a_buffer_of_another_job_version_is_refused(small_job: Path, tmp_path: Path) -> None:
    """One consistent state: an objective renamed since `run` is refused in one line
    (exit 2) before anything is served; --force inspects it anyway."""
    data = yaml.safe_load(small_job.read_text())
    data["objectives"][0]["name"] = "renamed"
    other = tmp_path / "job.yaml"
    other.write_text(yaml.safe_dump(data, sort_keys=False))
    buffer = small_job.parent / "out" / "buffer.npz"
    result = sensaov("view", str(other), "--port", "0", "--buffer", str(buffer))
    assert result.returncode == EXIT_BAD_INPUT and result.stdout == ""
    (line,) = result.stderr.splitlines()
    assert "made by another version of job.yaml" in line and "--force" in line


def test_a_view_paints_the_buffer_values_and_a_pick_lists_the_gradients(
    server: ViewServer, session: ViewSession
) -> None:
    """The EXR layer holds the objects' aggregates of their trusted gradients (the headline
    view) at fully covered pixels, and a pick reports the stored value and gradient
    of each of the object's parameters."""
    buffer = read_buffer(session.buffer_path)
    trusted = [p.key for p in buffer.params if is_trusted(p)]
    assert len(trusted) < len(buffer.params)  # the demo holds biased gradients: left out here
    # the objects channel paints the default score, the signed sum (docs/rankings.md, "One score")
    scores = per_object(buffer, "mean_luma", method="sum", weight="value", keys=trusted)
    sums = per_object(buffer, "mean_luma", method="sum", weight="value", keys=trusted)
    status, _, body = get(server.url + "api/view?channel=objects&format=exr&spp=4&width=64")
    assert status == 200
    exr = Path(session.job.output) / "view-test.exr"
    exr.write_bytes(body)
    channels, header = read_exr(exr)
    exr.unlink()
    layer = channels["mean_luma.objects.Y"]
    status, _, ids = get(server.url + "api/view?channel=objects&format=ids&spp=4&width=64")
    index = np.frombuffer(ids, "<i4").reshape(layer.shape)
    query = {"channel": "objects", "spp": "4", "width": "64"}
    visibility = session.visibility(session.request(query))
    full = visibility.rank_coverage[..., 0] == 1.0
    for i, name in enumerate(buffer.objects):
        where = full & (index == i)
        if where.any():
            expected = math.copysign(abs(scores[name]), sums[name])
            assert layer[where] == pytest.approx(expected, rel=1e-5), name
    assert "normalize=shared" in header["sensaov/encoding"]
    _, _, body = get(server.url + "api/pick?object=right_wall")
    pick = json.loads(body)
    row = pick["parameters"][0]
    assert row["key"] == "green.reflectance.value"
    assert row["value"] == pytest.approx(buffer.value(row["key"]).tolist())
    assert row["gradient"] == pytest.approx(buffer.grad("mean_luma", row["key"]).tolist())
    assert row["trust"] == "verified" and pick["object_rank"] >= 1


@pytest.mark.parametrize(
    ("query", "reason"),
    [
        ("fov=180", "fov 180 is outside (0, 180) degrees"),
        ("origin=0,0,0&target=0,0,0", "bad camera: target must differ from origin"),
        ("up=0,0,1", "bad camera: up must not be zero or parallel to target - origin"),
        ("origin=1,2", "origin must be three finite numbers x,y,z, got '1,2'"),
        ("origin=1,nan,2", "origin must be three finite numbers x,y,z, got '1,nan,2'"),
        ("width=0", "width 0 is outside [1, 2048]"),
        ("spp=x", "spp must be an integer, got 'x'"),
        ("sign=both", "sign must be one of signed, magnitude, got 'both'"),
        ("spp=1&spp=2", "parameter 'spp' is given 2 times"),
        ("zoom=2", "unknown parameter 'zoom'"),
        ("channel=nope", "no channel 'nope' in the buffer"),
        ("objective=nope", "no objective 'nope' in the buffer"),
        ("channel=select:nothing*", "select query 'nothing*' matches no parameter"),
        ("channel=forward.light&origin=1,1,3", "channel 'forward.light' is a forward layer"),
    ],
)
def test_bad_values_get_400_and_one_line(server: ViewServer, query: str, reason: str) -> None:
    status, headers, body = get(server.url + "api/view?" + query)
    assert status == 400 and headers["Content-Type"].startswith("text/plain")
    text = body.decode()
    assert text.startswith(reason) and text.count("\n") == 1


def test_a_pick_outside_the_image_and_an_unknown_page_are_refused(server: ViewServer) -> None:
    assert get(server.url + "api/pick?x=256&y=0")[0] == 400
    assert get(server.url + "api/pick?x=1")[0] == 400
    assert get(server.url + "nope")[0] == 404


def test_the_shared_scale_is_the_one_project_paints_with(
    server: ViewServer, session: ViewSession, small_job: Path
) -> None:
    """Fig. 6 across tools: the page's shared scale of `mean_luma.objects` is the display scale
    `project` records for that layer in every camera's EXR (one function, p95 rule); the
    view's own scale is p95 of its own pixels and says so."""
    done = sensaov("project", "-q", str(small_job))
    assert done.returncode == 0, done.stderr
    recorded = set()
    for camera in session.job.projected_cameras():
        _, header = read_exr(session.job.output / f"{camera.name}.exr")
        recorded |= {value for key, value in header.items()
                     if key.endswith("/display_scale") and header.get(key.replace(
                         "/display_scale", "/name")) == "mean_luma.objects"}  # fmt: skip
    assert len(recorded) == 1
    shared = float(recorded.pop())
    for pose in ("", "&origin=1,1,3"):  # the objective camera, then a free one
        status, headers, _ = get(server.url + "api/view?channel=objects&width=32" + pose)
        legend = json.loads(headers["X-Sensaov-Legend"])
        assert status == 200 and legend["peak"] == pytest.approx(shared, rel=1e-12)
        assert legend["notes"][0].startswith("scale: p95 of |v| over the non-zero pixels of")
    _, headers, body = get(server.url + "api/view?channel=objects&width=32&scale=view&format=exr")
    own = json.loads(headers["X-Sensaov-Legend"])
    exr = session.job.output / "view-own.exr"
    exr.write_bytes(body)
    channels, _ = read_exr(exr)
    exr.unlink()
    values = np.abs(channels["mean_luma.objects.Y"].astype(np.float64))
    painted = values[values > 0]
    assert own["notes"][0].startswith("scale: p95 of |v| over this view's pixels")
    assert np.mean(painted > own["peak"] * 1.001) <= 0.05 < np.mean(painted >= own["peak"] * 0.999)


def test_forward_layers_are_served_at_the_objective_camera_only(server: ViewServer) -> None:
    status, headers, body = get(server.url + "api/view?channel=forward.green_wall&format=exr")
    assert status == 200
    legend = json.loads(headers["X-Sensaov-Legend"])
    assert legend["scale_mode"] == "image" and legend["peak"] > 0
    status, headers, _ = get(server.url + "api/view?channel=transport_green_wall&width=32")
    (note,) = json.loads(headers["X-Sensaov-Legend"])["notes"]
    assert status == 200 and note.startswith("duality residual") and note.endswith("agrees")


def test_a_texel_field_is_painted_through_the_hit_uvs_of_a_new_viewpoint(
    server: ViewServer, session: ViewSession
) -> None:
    """The checker wall's texel panel lands on the checker wall only, from a moved camera."""
    camera = "origin=1.5,0.3,3&spp=4&width=64"
    channel = "texels_checker_reflectance_texel"
    status, headers, body = get(server.url + f"api/view?channel={channel}&{camera}&format=exr")
    assert status == 200, body
    exr = Path(session.job.output) / "texel-test.exr"
    exr.write_bytes(body)
    channels, _ = read_exr(exr)
    exr.unlink()
    layer = channels[f"mean_luma.{channel}.Y"]
    _, _, ids = get(server.url + f"api/view?{camera}&format=ids")
    index = np.frombuffer(ids, "<i4").reshape(layer.shape)
    wall = index == session.buffer.objects.index("left_wall")
    assert wall.sum() > 100 and np.count_nonzero(layer[wall]) > 0.9 * wall.sum()
    near = np.pad(wall, 1)  # pixels beside the wall may hold some of its coverage
    near = np.any([near[1 + dy : near.shape[0] - 1 + dy, 1 + dx : near.shape[1] - 1 + dx]
                   for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)  # fmt: skip
    assert not np.any(layer[~near])
    assert "fixed by the job's texel channel" in json.loads(headers["X-Sensaov-Legend"])["encoding"]


def test_other_hosts_and_cross_site_saves_are_refused(server: ViewServer) -> None:
    """DNS rebinding sends a foreign Host header; a cross-site form cannot set X-Sensaov."""
    host, port = server.server_address[:2]
    connection = http.client.HTTPConnection(str(host), port, timeout=30)
    connection.request("GET", "/api/meta", headers={"Host": f"evil.example:{port}"})
    assert connection.getresponse().status == 403
    status, _, _ = get(server.url + "api/camera?name=v", method="POST")
    assert status == 403


def test_a_moved_camera_reuses_the_compiled_kernel(session: ViewSession) -> None:
    """Every number of the camera is opaque: new poses, sizes and spp compile nothing."""
    import drjit as dr

    tracer: ViewTracer = session.tracer
    first = session.objective_camera.pose
    tracer.trace(first, 32, 32, 1)
    moved = Pose(LookAt((2.0, 1.0, 3.0), (0.1, 0.0, 0.0), (0.0, 1.0, 0.0)), 55.0)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()  # empty it
        for width, height, spp in ((32, 32, 1), (48, 20, 1), (32, 32, 16)):
            tracer.trace(moved, width, height, spp)
        launched = [k for k in dr.kernel_history() if "cache_hit" in k]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert launched and all(k["cache_hit"] for k in launched)


def test_rays_match_mitsubas_perspective_sensor(session: ViewSession) -> None:
    """A viewpoint saved as a look_at camera renders what the live view showed."""
    mi = session.loaded.mi
    look = LookAt((1.0, 0.5, 3.0), (0.1, -0.2, 0.0), (0.0, 1.0, 0.2))
    transform = mi.ScalarTransform4f().look_at(origin=look.origin, target=look.target, up=look.up)
    sensor = mi.load_dict({"type": "perspective", "fov": 50.0, "to_world": transform,
                           "film": {"type": "hdrfilm", "width": 40, "height": 30}})  # fmt: skip
    film = mi.Point2f(mi.Float([0.1, 0.9, 0.5, 0.3]), mi.Float([0.2, 0.7, 0.5, 0.95]))
    theirs, _ = sensor.sample_ray(0.0, 0.5, film, mi.Point2f(0.5, 0.5))
    from sensaov_cli.render.visibility import _frame

    ours = session.tracer._ray(_frame(Pose(look, 50.0), 40, 30), film)
    assert np.array(ours.d) == pytest.approx(np.array(theirs.d), abs=1e-6)
    assert np.array(ours.o) == pytest.approx(np.array(theirs.o), abs=1e-6)
    pose = sensor_pose(mi, sensor, session.bounds)
    assert pose.look_at.origin == pytest.approx(look.origin, abs=1e-6) and pose.fov == 50.0


def test_a_saved_viewpoint_projects_to_the_view_it_was_saved_from(
    server: ViewServer, session: ViewSession
) -> None:
    camera = "origin=2,1.2,3&target=0,0,-0.2&up=0,1,0&fov=45&width=40&height=30"
    status, _, body = get(server.url + f"api/camera?{camera}&name=corner")
    entry = yaml.safe_load(json.loads(body)["yaml"])[0]
    assert status == 200 and entry["look_at"]["origin"] == [2.0, 1.2, 3.0]
    saving = {"X-Sensaov": "save"}
    status, _, body = get(server.url + f"api/camera?{camera}&name=corner", saving, "POST")
    assert status == 200, body
    copy = Path(json.loads(body)["path"])
    assert copy.parent == session.job.output
    job = load_job(copy)
    assert job.scene == session.job.scene and job.output == session.job.output
    assert [c.name for c in job.inspection_cameras][-1] == "corner"
    status, _, body = get(server.url + f"api/camera?{camera}&name=corner", saving, "POST")
    assert status == 400 and b"already has an inspection camera named 'corner'" in body
    done = sensaov("project", "-q", str(copy), "--camera", "corner", "--beauty-spp", "0")
    assert done.returncode == 0, done.stderr
    channels, header = read_exr(session.job.output / "corner.exr")
    _, _, ids = get(server.url + f"api/view?{camera}&format=ids&spp=16")
    live = np.frombuffer(ids, "<i4").reshape(30, 40)
    manifest = json.loads(header["cryptomatte/" + _crypto_key(header) + "/manifest"])
    by_id = {np.uint32(int(h, 16)).view(np.float32): name for name, h in manifest.items()}
    top = channels["CryptoObject00.R"]
    names = np.array([by_id.get(v, "") for v in top.ravel()]).reshape(top.shape)
    objects = np.array(["", *session.buffer.objects])[live + 1]
    assert np.mean(names == objects) > 0.97  # same camera; only edge pixels may differ


def _crypto_key(header: dict[str, Any]) -> str:
    return next(k.split("/")[1] for k, v in header.items() if k.endswith("/name") and
                v == "CryptoObject")  # fmt: skip


def test_view_query_defaults_to_the_objective_camera(session: ViewSession) -> None:
    first = session.objective_camera
    request = view_request({}, first.pose, 1.0, "mean_luma", "objects")
    assert request.pose == first.pose and (request.width, request.height, request.spp) == (
        256, 256, 1)  # fmt: skip
    with pytest.raises(RequestError, match="unknown parameter 'x'"):
        single_values({"x": ["1"]}, ("y",))


@pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))
def test_the_page_orbits_on_a_drag_and_shows_a_clicked_object(
    server: ViewServer, tmp_path: Path
) -> None:
    shots = Path(SHOTS) if SHOTS else tmp_path
    shots.mkdir(parents=True, exist_ok=True)
    browser = Browser()
    status = "return document.getElementById('status').textContent"
    camera = "return document.getElementById('camera-text').textContent"
    try:
        browser.get(server.url)
        browser.wait_for(status + ".includes('16 spp')")
        before = browser.script(camera)
        browser.screenshot(shots / "view-objective.png")
        browser.drag("#stage", (0, 0), [(25, 4)] * 6)
        browser.wait_for(camera + f" !== {json.dumps(before)}")
        browser.wait_for(status + ".includes('16 spp')")
        assert "(moved)" in browser.script(camera)
        browser.click("#stage", (0, -60))  # the back wall, above the boxes
        picked = browser.wait_for(
            "const p = document.getElementById('pick-object'); return p && p.textContent"
        )
        assert picked in server.session.buffer.objects
        assert browser.script("return document.querySelectorAll('#sunburst path.hot').length") >= 1
        browser.wait_for("return document.getElementById('overlay').width > 0")
        browser.screenshot(shots / "view-orbited-picked.png")
    finally:
        browser.close()
    assert (shots / "view-orbited-picked.png").stat().st_size > 10_000


def test_a_view_over_the_memory_budget_is_refused_before_tracing(
    server: ViewServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Width, height and spp come from a request: checked against the budget like a job's."""
    monkeypatch.setenv("SENSAOV_MEMORY_BUDGET", "64M")
    status, _, body = get(server.url + "api/view?width=2048&height=2048&spp=256")
    assert status == 400
    assert b"width x height = 2048x2048 at spp = 256" in body and b"memory budget" in body
    assert len(body.decode().splitlines()) == 1
    monkeypatch.delenv("SENSAOV_MEMORY_BUDGET")
    assert get(server.url + "api/view?width=32")[0] == 200  # the server still answers


@pytest.mark.parametrize(
    "kind", ["link to the buffer", "link to the scene", "FIFO", "edited into no job"]
)
def test_a_save_never_replaces_an_input_or_opens_a_special_file(
    server: ViewServer, session: ViewSession, kind: str
) -> None:
    """The job's copy is the one file the view writes: when its name leads to the buffer, a
    scene file or a FIFO, the save is refused (400, one line) and nothing changes on disk."""
    copy = copy_path(session.job)
    kept = copy.with_name("kept.yaml")
    if copy.exists():
        copy.rename(kept)
    targets = {"link to the buffer": session.buffer_path, "link to the scene": session.job.scene}
    try:
        if kind == "FIFO":
            os.mkfifo(copy)
        elif kind == "edited into no job":
            copy.write_text("version: 1\nscene: [unclosed\n")
        else:
            copy.symlink_to(targets[kind])
        before = {p: p.read_bytes() for p in targets.values()}
        status, _, body = get(server.url + "api/camera?name=elsewhere", {"X-Sensaov": "1"}, "POST")
        assert status == 400 and len(body.decode().splitlines()) == 1, body
        expected = {"FIFO": b"not a regular file", "edited into no job": copy.name.encode()}
        assert expected.get(kind, b"would replace") in body, body
        assert {p: p.read_bytes() for p in targets.values()} == before
    finally:
        copy.unlink()
        if kept.exists():
            kept.rename(copy)


# Every pointer event the stage sees, with the buttons held and the camera the page shows right
# after the page's own handlers ran (this listener is added after them).
_RECORD_EVENTS = """
window.seen = [];
const stage = document.getElementById('stage');
const camera = () => document.getElementById('camera-text').textContent;
for (const type of ['pointerdown', 'pointermove', 'pointerup', 'pointercancel', 'dragstart',
                    'lostpointercapture'])
  stage.addEventListener(type, (e) => window.seen.push([type, e.buttons, camera()]));
"""
_STATUS = "return document.getElementById('status').textContent"
_CAMERA = "return document.getElementById('camera-text').textContent"


@pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))
def test_a_drag_of_small_steps_orbits_at_every_step_and_a_hover_moves_nothing(
    server: ViewServer,
) -> None:
    """As a person drags in Chromium (real pointer events): the browser's own image drag never
    takes the pointer (no dragstart, no pointercancel), every step of the drag turns the
    camera, and moving the mouse after the release, no button down, leaves it where it is."""
    steps = 24
    browser = Browser()
    try:
        browser.get(server.url)
        browser.wait_for(_STATUS + ".includes('16 spp')")
        browser.script(_RECORD_EVENTS)
        browser.drag("#stage", (-60, 0), [(5, 1)] * steps, step_ms=16)
        seen = browser.script("return window.seen")
        types = [event[0] for event in seen]
        assert "dragstart" not in types and "pointercancel" not in types, types
        seen = seen[types.index("pointerdown") :]  # from the press on (the pointer came first)
        types = [event[0] for event in seen]
        assert "pointerup" in types, types
        held = [i for i, event in enumerate(seen) if event[0] == "pointermove" and event[1] == 1]
        assert len(held) >= steps, types
        unchanged = [i for i in held if seen[i][2] == seen[i - 1][2]]
        assert not unchanged, [seen[i] for i in unchanged]
        after_drag = browser.script(_CAMERA)
        assert "(moved)" in after_drag
        browser.script("window.seen = []")
        browser.hover("#stage", (40, 20), [(-6, -2)] * 20, step_ms=16)
        hovered = browser.script("return window.seen")
        assert len(hovered) >= 20 and all(event[1] == 0 for event in hovered), hovered
        assert {event[2] for event in hovered} == {after_drag}
        assert browser.script(_CAMERA) == after_drag
    finally:
        browser.close()


@pytest.mark.skipif(browser_missing() is not None, reason=str(browser_missing()))
def test_the_pick_panel_follows_the_objective_and_the_legend_speaks_words(
    server: ViewServer,
) -> None:
    """A clicked object's panel is redrawn for the objective switched to (its rank there,
    never the old objective's), and the legend says its encoding in words (the exact string
    stays as their tooltip)."""
    browser = Browser()
    rank = "const r = document.getElementById('pick-rank'); return r && r.textContent"
    try:
        browser.get(server.url)
        browser.wait_for(_STATUS + ".includes('16 spp')")
        browser.click("#stage", (0, -60))  # the back wall
        first = browser.wait_for(rank)
        picked = browser.script("return document.getElementById('pick-object').textContent")
        assert first.startswith("in mean_luma · objects:"), first
        browser.script(
            "const o = document.getElementById('objective'); o.value = 'back_wall_luma';"
            "o.dispatchEvent(new Event('change'));"
        )
        shown = browser.wait_for(
            rank + " && r.textContent.includes('back_wall_luma') && r.textContent"
        )
        _, _, body = get(server.url + f"api/pick?objective=back_wall_luma&object={picked}")
        expected = json.loads(body)
        assert shown.startswith("in back_wall_luma · objects:")
        assert f"rank {expected['object_rank']} of {expected['objects_ranked']}" in shown
        words = browser.script("return document.getElementById('legend-words').textContent")
        exact = browser.script("return document.getElementById('legend-words').title")
        assert exact.startswith("weight=value;sign=signed;aggregate=sum")  # the default score
        assert "=" not in words and "θ·∂M/∂θ" in words and "summed per object" in words
    finally:
        browser.close()


def test_concurrent_saves_keep_every_camera(server: ViewServer, session: ViewSession) -> None:
    """Many pages save at once: every save answered 200 is in the job's copy, none lost to
    another's read-modify-write."""
    copy = copy_path(session.job)
    before = load_job(copy if copy.exists() else session.job.path).inspection_cameras
    names = [f"crowd_{i}" for i in range(12)]
    start = threading.Barrier(len(names))
    answers: dict[str, int] = {}

    def save(name: str) -> None:
        start.wait()
        url = server.url + f"api/camera?name={name}&origin=2,1,{2 + len(answers) * 0.01}"
        answers[name] = get(url, {"X-Sensaov": "1"}, "POST")[0]

    threads = [threading.Thread(target=save, args=(name,)) for name in names]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert answers == dict.fromkeys(names, 200)
    saved = {c.name for c in load_job(copy).inspection_cameras} - {c.name for c in before}
    assert saved == set(names)


@pytest.mark.parametrize(
    ("query", "reason"),
    [
        ("width=%C2%B2", "width must be an integer, got '²'"),
        ("width=--5", "width must be an integer, got '--5'"),
        ("width=" + "9" * 5000, "width '9999999999"),
        ("spp=%D9%A1", "spp must be an integer, got '١'"),
        ("fov=%D9%A3%D9%A0", "fov must be a number, got '٣٠'"),
        ("fov=1_0", "fov must be a number, got '1_0'"),
        ("fov=" + "4" * 5000, "fov must be a number, got '4444"),
        ("fov=inf", "fov must be finite, got 'inf'"),
        ("fov=1e999", "fov must be finite, got '1e999'"),
        ("origin=1,2," + "3" * 5000, "origin must be three finite numbers x,y,z, got '1,2,333"),
        ("sign=" + "x" * 5000, "sign must be one of signed, magnitude, got 'xxxx"),
        ("%FF=1", "unknown parameter '\ufffd'"),
    ],
)
def test_hostile_numbers_get_400_and_one_short_line(
    server: ViewServer, query: str, reason: str
) -> None:
    """Numbers are ASCII digits of a bounded length: other scripts' digits, doubled signs and
    numbers of thousands of digits are refused as bad values, never a 500 with Python's error,
    and the line quotes only the start of a long value."""
    status, headers, body = get(server.url + "api/view?" + query)
    text = body.decode()
    assert status == 400 and headers["Content-Type"].startswith("text/plain"), text
    assert text.startswith(reason) and text.count("\n") == 1 and len(text) < 400, text
    status, _, body = get(server.url + "api/pick?x=" + "1" * 5000 + "&y=1")
    assert status == 400 and body.decode().startswith("x '1111"), body


@contextmanager
def _closing_server(
    session: ViewSession, log: list[str], on_save: Any = None, host: str = "127.0.0.1"
) -> Iterator[ViewServer]:
    running = ViewServer((host, 0), on_save or (lambda text: None), log.append)
    running.attach(session)
    thread = threading.Thread(target=running.serve_forever, kwargs={"poll_interval": 0.05})
    thread.start()
    try:
        yield running
    finally:
        running.shutdown()
        running.server_close()
        thread.join()


def test_a_client_gone_mid_render_costs_one_log_line_and_no_traceback(
    session: ViewSession, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The client resets its connection while its view is painted: the answer cannot be
    written, the server says so in one --log line and keeps answering."""
    gone, painting = threading.Event(), threading.Event()
    paint = session.view

    def slow_view(request: Any) -> Any:
        painting.set()
        gone.wait(60)
        return paint(request)

    monkeypatch.setattr(session, "view", slow_view)
    log: list[str] = []
    with _closing_server(session, log) as running:
        host, port = running.server_address[:2]
        client = socket.create_connection((str(host), port))
        client.sendall(f"GET /api/view?width=16 HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode())
        assert painting.wait(60)
        client.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\1\0\0\0\0\0\0\0")  # reset
        client.close()
        gone.set()
        monkeypatch.setattr(session, "view", paint)
        assert get(running.url + "api/view?width=16")[0] == 200  # answered after the loss
    left = [line for line in log if "left before its answer" in line]
    assert len(left) == 1 and left[0].startswith("/api/view?width=16:"), log
    assert "Traceback" not in capfd.readouterr().err


def test_a_save_stands_when_stdout_is_gone_and_its_error_names_the_copy(
    session: ViewSession, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A saved camera is in the copy and the page is told so (200) even when stdout, where it
    is echoed, is a closed pipe; a copy that fails validation is refused naming the copy, not
    the temporary file it was checked in."""
    import sensaov_cli.live.server as live_server

    def closed(text: str) -> None:
        raise BrokenPipeError(32, "Broken pipe")

    log: list[str] = []
    copy = copy_path(session.job)
    with _closing_server(session, log, on_save=closed) as running:
        status, _, body = get(running.url + "api/camera?name=piped", {"X-Sensaov": "1"}, "POST")
        assert status == 200 and json.loads(body)["path"] == str(copy), body
        assert "piped" in {c.name for c in load_job(copy).inspection_cameras}
        assert any("not printed on stdout" in line for line in log), log
        original = live_server.job_copy_text
        monkeypatch.setattr(
            live_server, "job_copy_text", lambda *a: original(*a) + "no_such_key: 1\n"
        )
        before = copy.read_bytes()
        status, _, body = get(running.url + "api/camera?name=broken", {"X-Sensaov": "1"}, "POST")
        line = body.decode()
        assert status == 400 and line.startswith(f"{copy}:") and ".tmp" not in line, line
        assert "no_such_key" in line and copy.read_bytes() == before
        assert not list(copy.parent.glob(f".{copy.name}.*"))  # no temporary left behind


def test_the_host_check_names_exactly_the_served_address(session: ViewSession) -> None:
    """On another loopback address only that address is a valid Host; on 127.0.0.1 the
    address and localhost; a foreign name never (DNS rebinding)."""
    port = free_port()
    other = ViewServer(("127.0.0.2", port), lambda text: None, None)
    try:
        assert other.host_allowed(f"127.0.0.2:{port}")
        for refused in ("localhost", "127.0.0.1", "evil.example", "[::1]", "127.0.0.2"):
            assert not other.host_allowed(f"{refused}:{port}" if refused != "127.0.0.2" else
                                          refused), refused  # fmt: skip
        assert not other.host_allowed(None)
    finally:
        other.server_close()
    first = ViewServer(("127.0.0.1", 0), lambda text: None, None)
    try:
        port = first.server_address[1]
        assert first.host_allowed(f"127.0.0.1:{port}") and first.host_allowed(f"LOCALHOST:{port}")
        assert not first.host_allowed(f"[::1]:{port}") and not first.host_allowed(f"x:{port}")
    finally:
        first.server_close()


def _ipv6_loopback() -> bool:
    try:
        with socket.socket(socket.AF_INET6) as probe:
            probe.bind(("::1", 0))
        return True
    except OSError:
        return False


def test_view_listens_on_the_ipv6_loopback_or_says_why_not(session: ViewSession) -> None:
    from sensaov_cli.errors import ServerError
    from sensaov_cli.live.server import listen

    with pytest.raises(ServerError, match=r"192\.0\.2\.1:0: .*\(choose another --host"):
        listen("192.0.2.1", 0, on_save=lambda text: None)  # an address this machine lacks
    if not _ipv6_loopback():  # this machine has no ::1: the line says so, and of the host
        with pytest.raises(
            ServerError, match=r"cannot listen on \[::1\]:0: .*choose another --host"
        ):
            listen("::1", 0, on_save=lambda text: None)
        return
    log: list[str] = []
    with _closing_server(session, log, host="::1") as running:
        assert running.url.startswith("http://[::1]:")
        status, _, body = get(running.url + "api/meta")
        assert status == 200 and json.loads(body)["format"] == "sensaov-view"


def test_request_lines_are_logged_with_control_characters_escaped(session: ViewSession) -> None:
    log: list[str] = []
    with _closing_server(session, log) as running:
        host, port = running.server_address[:2]
        with socket.create_connection((str(host), port)) as client:
            line = f"GET /\x1b[2J\x1b]0;pwned\x07 HTTP/1.1\r\nHost: {host}:{port}\r\n"
            client.sendall(line.encode() + b"Connection: close\r\n\r\n")
            assert client.recv(100).startswith(b"HTTP/1.1 404")
    logged = "\n".join(log)
    assert "\x1b" not in logged and "\x07" not in logged
    assert "\\x1b[2J\\x1b]0;pwned\\x07" in logged


def test_shared_scales_are_kept_by_what_a_channel_means_not_its_name(
    session: ViewSession,
) -> None:
    """A typed query and a job channel that share a name (a job may name a channel like an
    automatic one) never share a scale; the same selection under two names shares one."""
    from dataclasses import replace

    from sensaov_cli.views.channels import shared_channel_scale

    walls = session.sources.find("mean_luma", "walls")
    query = session.sources.find("mean_luma", "select:*.alpha*")
    assert isinstance(walls, ChannelValues) and isinstance(query, ChannelValues)
    disguised = replace(query, spec=replace(query.spec, name="walls"))
    ours = session.scales.of(walls, "signed")
    theirs = session.scales.of(disguised, "signed")
    expected = shared_channel_scale(
        session.buffer, replace(query.spec, tonemap="none", normalize="none"), "mean_luma",
        session.scales._visibilities(), untrusted=session.job.views.untrusted,
        percentile=session.job.views.percentile,
    )  # fmt: skip
    assert theirs == expected and theirs.value != ours.value
    same = session.sources.find("mean_luma", "select:*reflectance*")
    assert isinstance(same, ChannelValues)
    assert session.scales.of(same, "signed") == ours
