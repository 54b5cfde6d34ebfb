"""Big scenes: what is not ranked is counted in a line per kind past ``--top``, listed with
``--all``, and kept whole in JSON and CSV (a scene of hundreds of small objects)."""

from __future__ import annotations

import csv
import io
import json
import math
import re
from pathlib import Path
from typing import Any

import pytest

from sensaov_cli.outputs.tables import zero_value_legend
from sensaov_cli.views.hierarchy import ZeroValued

from .conftest import sensaov, use_scene

SPHERES = 196  # a 14 x 14 grid; the camera frames about 7 x 7 of them
PLASTIC_EVERY = 5  # roughplastic: its gradients are biased, so left out of objects


def sphere_grid(path: Path, count: int) -> Path:
    """Many small spheres, most outside a narrow frame; direct light only (max_depth 2), so an
    unseen sphere's reflectance gets no gradient at all."""
    side = math.ceil(math.sqrt(count))
    shapes = []
    for i in range(count):
        x, y = (i % side - side / 2) * 0.5, (i // side - side / 2) * 0.5
        bsdf = (
            '<bsdf type="roughplastic"><rgb name="diffuse_reflectance" value="0.4"/></bsdf>'
            if i % PLASTIC_EVERY == 0
            else '<bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>'
        )
        shapes.append(
            f'<shape type="sphere" id="s{i}"><point name="center" x="{x}" y="{y}" z="0"/>'
            f'<float name="radius" value="0.2"/>{bsdf}</shape>'
        )
    path.write_text(
        '<scene version="3.0.0">'
        '<integrator type="path"><integer name="max_depth" value="2"/></integrator>'
        '<sensor type="perspective" id="sensor"><float name="fov" value="20"/>'
        '<transform name="to_world"><lookat origin="0,0,10" target="0,0,0" up="0,1,0"/>'
        '</transform><film type="hdrfilm"><integer name="width" value="24"/>'
        '<integer name="height" value="24"/></film></sensor>'
        '<emitter type="constant"><rgb name="radiance" value="1"/></emitter>'
        + "".join(shapes)
        + "</scene>"
    )
    return path


@pytest.fixture(scope="module")
def big_buffer(job_writer: Any) -> Path:
    job = job_writer(
        "spheres", render={"spp": 4, "seed": 0, "resolution": [24, 24]}, repair={"budget": 0}
    )
    use_scene(job, sphere_grid(job.parent / "spheres.xml", SPHERES))
    done = sensaov("run", "-q", str(job))
    assert done.returncode == 0, done.stderr
    return job.parent / "out" / "buffer.npz"


def _json(buffer: Path, *args: str) -> dict[str, Any]:
    done = sensaov("rank", str(buffer), "--json", *args)
    assert done.returncode == 0, done.stderr
    document: dict[str, Any] = json.loads(done.stdout)
    return document


def test_the_summary_counts_what_it_does_not_rank(big_buffer: Path) -> None:
    (objective,) = _json(big_buffer, "--top", "5")["objectives"]
    no_gradient = [p["key"] for p in objective["no_gradient"]]
    left_out = [o["name"] for o in objective["left_out"]["objects"]]
    assert len(no_gradient) > 100 and len(left_out) > 5  # the scene does what it is for
    text = sensaov("rank", str(big_buffer), "--top", "5").stdout
    lines = text.splitlines()
    assert len(lines) < 45, text  # not one line per parameter
    assert f"not ranked: {len(no_gradient)} parameters (--all lists them), because:" in text
    (reason,) = [line for line in lines if re.match(r"\s+\d+: Mitsuba", line)]
    assert int(reason.split(":")[0]) == len(no_gradient)  # one reason, with its count
    assert not any(key in text for key in no_gradient)
    shown = [name for name in left_out if re.search(rf"^\s+{name}\s", text, re.MULTILINE)]
    assert shown == left_out[:5]
    more = f"... {len(left_out) - 5} more objects with untrusted gradients (--all lists them)"
    assert more in text
    # the run's repairs: none within repair.budget 0, counted by reason, not one line per key
    assert re.search(r"^  not repaired, still labelled: \d+ parameters \(--all lists them\): "
                     r"over the repair budget", text, re.MULTILINE)  # fmt: skip


def test_all_lists_everything_not_ranked(big_buffer: Path) -> None:
    (objective,) = _json(big_buffer, "--top", "5")["objectives"]
    text = sensaov("rank", str(big_buffer), "--top", "5", "--all").stdout
    for entry in objective["no_gradient"]:
        assert f"      {entry['key']} ({entry['owners'][0]}): {entry['note']}" in text
    for entry in objective["left_out"]["objects"]:
        assert re.search(rf"^\s+{entry['name']}\s", text, re.MULTILINE)
    assert "--all lists them" not in text


def test_a_cut_counts_them_too_and_csv_keeps_every_row(big_buffer: Path) -> None:
    args = ("--by", "object", "--top", "5")
    (objective,) = _json(big_buffer, *args)["objectives"]
    assert len(objective["left_out"]) > 5 and len(objective["no_gradient"]) > 100
    text = sensaov("rank", str(big_buffer), *args).stdout
    assert len(text.splitlines()) < 40, text
    assert f"... {len(objective['left_out']) - 5} more rows left out (--all lists them)" in text
    assert f"not ranked: {len(objective['no_gradient'])} parameters" in text
    table = sensaov("rank", str(big_buffer), *args, "--csv").stdout
    rows = list(csv.DictReader(io.StringIO(table)))
    assert len(rows) == len(objective["rows"]) + len(objective["left_out"])
    full = sensaov("rank", str(big_buffer), *args, "--all").stdout
    assert "--all lists them" not in full and len(full.splitlines()) > len(objective["no_gradient"])


def test_zero_values_past_the_limit_are_counted() -> None:
    found = [ZeroValued(f"k{i}.value", (f"o{i}",), 3, 3, 0.1 * i) for i in range(12)]
    lines = zero_value_legend(found, 4)
    assert [line.split()[0] for line in lines[1:5]] == ["k0.value", "k1.value", "k2.value",
                                                        "k3.value"]  # fmt: skip
    assert lines[5:] == ["      ... 8 more parameters of value 0 (--all lists them)"]
    assert len(zero_value_legend(found)) == 13  # no limit: every one
