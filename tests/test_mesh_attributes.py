"""Mesh attributes a ``mesh_attribute`` texture reads (a PLY's vertex or face colours) are that
texture's data, not geometry: selected, typed by the slot the texture fills, scored to their
object, and their gradients agree with finite differences."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.buffer.npz import read_buffer

from .conftest import ROOT, sensaov

SCENE = ROOT / "tests" / "scenes" / "mesh_attributes.xml"
RENDER = {"spp": 8, "resolution": [16, 16], "seed": 0}


@pytest.fixture(scope="module")
def job(job_writer: Callable[..., Path]) -> Path:
    path = job_writer("mesh_attributes", render=RENDER)
    text = path.read_text().replace(str(ROOT / "scenes" / "cbox" / "scene.xml"), str(SCENE))
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def buffer(job: Path) -> Path:
    done = sensaov("run", str(job), "-q")
    assert done.returncode == 0, done.stderr
    return job.parent / "out" / "buffer.npz"


def test_params_selects_and_labels_a_mesh_attribute_as_its_slot(job: Path) -> None:
    done = sensaov("params", str(job), "--json")
    assert done.returncode == 0, done.stderr
    listed = json.loads(done.stdout)
    selected = {p["key"]: p for p in listed["selected"]}
    painted, lamp = selected["painted.vertex_color"], selected["lamp.face_color"]
    assert (painted["type"], painted["plugin"], painted["owners"]) == (
        "reflectance", "diffuse", ["painted"],
    )  # fmt: skip
    assert (lamp["type"], lamp["plugin"], lamp["owners"]) == ("radiance", "area", ["lamp"])
    assert "mesh_attribute" in painted["flags"] and "mesh_attribute" in lamp["flags"]
    excluded = {p["key"]: p["reason"] for p in listed["excluded"]}
    assert "no mesh_attribute texture reads" in excluded["plain.vertex_color"]
    assert excluded["painted.vertex_positions"].startswith("geometry")  # still geometry
    text = sensaov("params", str(job)).stdout
    assert "painted.vertex_color" in text and "mesh_attribute" in text


def test_run_scores_the_object_its_colours_paint(buffer: Path) -> None:
    stored = read_buffer(buffer)
    record = stored.param("painted.vertex_color")
    assert record.type == "reflectance" and record.owners == ("painted",)
    assert record.trust == "verified"
    gradient = stored.grad(stored.objectives[0].name, "painted.vertex_color")
    assert gradient.shape == (12,) and np.all(gradient > 0)  # brighter vertices, brighter image
    done = sensaov("rank", str(buffer), "--by", "object", "--json")
    assert done.returncode == 0, done.stderr
    rows = {row["name"]: row for row in json.loads(done.stdout)["objectives"][0]["rows"]}
    assert rows["painted"]["score"] > 0 and rows["painted"]["trust"] == "verified"
    assert rows["lamp"]["score"] > 0  # its face colours are its light


def test_the_gradient_of_vertex_colours_agrees_with_finite_differences(
    job: Path, buffer: Path
) -> None:
    done = sensaov("check", str(job), "--key", "painted.vertex_color", "--key", "lamp.face_color")
    assert done.returncode == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if ".vertex_color" in line]
    rows += [line for line in done.stdout.splitlines() if ".face_color" in line]
    assert len(rows) >= 4 and all("agrees" in row for row in rows), done.stdout


SHARED = """<scene version="3.0.0">
    <sensor type="perspective" id="sensor">
        <transform name="to_world">
            <lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="8"/>
            <integer name="height" value="8"/>
        </film>
    </sensor>
    <emitter type="constant" id="sky"/>
    <bsdf type="diffuse" id="vertex_paint">
        <texture type="mesh_attribute" name="reflectance">
            <string name="name" value="vertex_color"/>
        </texture>
    </bsdf>
    <shape type="ply" id="left">
        <string name="filename" value="{ply}"/>
        <transform name="to_world"><translate x="-1.2"/></transform>
        <ref id="vertex_paint"/>
    </shape>
    <shape type="ply" id="right">
        <string name="filename" value="{ply}"/>
        <transform name="to_world"><translate x="1.2"/></transform>
        <ref id="vertex_paint"/>
    </shape>
</scene>
"""


@pytest.mark.parametrize("shared", ["keep", "split"])
def test_a_shared_vertex_paint_colours_every_mesh_it_paints(
    job_writer: Callable[..., Path], shared: str
) -> None:
    path = job_writer(f"mesh_attributes_{shared}", parameters={"shared": shared})
    scene = path.parent / "shared.xml"
    ply = ROOT / "tests" / "scenes" / "vertex_colour_quad.ply"
    scene.write_text(SHARED.format(ply=ply))
    path.write_text(
        path.read_text().replace(str(ROOT / "scenes" / "cbox" / "scene.xml"), str(scene))
    )
    done = sensaov("params", str(path), "--json")
    assert done.returncode == 0, done.stderr
    selected = {p["key"]: p for p in json.loads(done.stdout)["selected"]}
    for mesh in ("left", "right"):
        record = selected[f"{mesh}.vertex_color"]
        assert record["type"] == "reflectance" and record["owners"] == [mesh]
