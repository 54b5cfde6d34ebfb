"""Property-based tests: no job text and no buffer bytes make the parser or the reader raise
anything but sensaov's own error types. Bounded for CI: max_examples and a deadline per example.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from sensaov_cli.buffer.npz import HEADER_MEMBER, read_buffer
from sensaov_cli.errors import SensaovError
from sensaov_cli.job.load import load_job
from tests.bad_buffers import write_buffer

from .bad_buffers import good_buffer, members, write_members
from .conftest import SCENES

BOUNDED = settings(
    max_examples=150,
    deadline=2000,  # ms per example; a parse takes ~1 ms
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=20))
values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4)
    ),
    max_leaves=20,
)
KEYS = ["version", "scene", "variant", "render", "objectives", "output", "channels",
        "parameters", "inspection_cameras", "objective_camera", "scene_args"]  # fmt: skip
GOOD = {
    "version": 1,
    "scene": str(SCENES / "cbox" / "scene.xml"),
    "objectives": [{"name": "m", "type": "mean_luminance"}],
}


def parse(tmp_path: Path, text: str | bytes) -> None:
    job = tmp_path / "job.yaml"
    job.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8", "surrogatepass"))
    try:
        load_job(job)
    except SensaovError:
        pass


@BOUNDED
@given(text=st.text(max_size=300))
def test_any_text_is_a_job_or_a_spec_error(tmp_path: Path, text: str) -> None:
    parse(tmp_path, text)


@BOUNDED
@given(data=st.binary(max_size=300))
def test_any_bytes_are_a_job_or_a_spec_error(tmp_path: Path, data: bytes) -> None:
    parse(tmp_path, data)


@BOUNDED
@given(changes=st.dictionaries(st.sampled_from(KEYS), values, max_size=4))
def test_any_values_under_the_known_keys(tmp_path: Path, changes: dict) -> None:
    parse(tmp_path, yaml.safe_dump({**GOOD, **changes}))


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("fuzz") / "good.npz"
    write_buffer(path, good_buffer())
    return path


def load(path: Path) -> None:
    try:
        read_buffer(path)
    except SensaovError:
        pass


@BOUNDED
@given(data=st.data())
def test_any_corruption_of_a_buffer_is_a_format_error(
    tmp_path: Path, good: Path, data: st.DataObject
) -> None:
    raw = bytearray(good.read_bytes())
    for _ in range(data.draw(st.integers(1, 8))):
        at = data.draw(st.integers(0, len(raw) - 1))
        raw[at] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(raw)))
    path = tmp_path / "buffer.npz"
    path.write_bytes(bytes(raw[:cut] if data.draw(st.booleans()) else raw))
    load(path)


@BOUNDED
@given(changes=st.dictionaries(st.text(max_size=12), values, max_size=3), drop=st.booleans())
def test_any_header_is_a_buffer_or_a_format_error(
    tmp_path: Path, good: Path, changes: dict, drop: bool
) -> None:
    items = members(good)
    out = []
    for name, blob in items:
        if name == f"{HEADER_MEMBER}.npy":
            header = json.loads(str(np.load(io.BytesIO(blob))))
            header.update(changes)
            stream = io.BytesIO()
            np.lib.format.write_array(stream, np.array(json.dumps(header)))
            blob = stream.getvalue()
        elif drop:
            continue
        out.append((name, blob))
    path = tmp_path / "buffer.npz"
    write_members(path, out)
    load(path)


@BOUNDED
@given(arrays=st.lists(st.binary(max_size=64), max_size=3))
@example(arrays=[b""])
def test_any_member_bytes_are_a_format_error(
    tmp_path: Path, good: Path, arrays: list[bytes]
) -> None:
    path = tmp_path / "buffer.npz"
    items = members(good)
    with zipfile.ZipFile(path, "w") as zf:
        for index, (name, blob) in enumerate(items):
            zf.writestr(name, arrays[index] if index < len(arrays) else blob)
    load(path)
