"""Mitsuba 0.5/0.6 scenes: upgraded where Mitsuba 3.9.1 has a counterpart, refused in one pass
where it has none, numbered meshes named after their material.

``tests/scenes/legacy_interior`` is our own interior written as Bitterli's 0.5 exports are:
numbered meshes, twosided walls, 8-bit textures with trilinear filtering and gamma, metals with
an exterior eta, glass with intIOR, an sRGB colour, a sunsky with 0.5's parameters,
``guided_path``, a Sobol sampler and an LDR film.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from sensaov_cli.errors import EXIT_BAD_INPUT, EXIT_OK
from sensaov_cli.scene import legacy
from tests.conftest import sensaov, use_scene, write_job

INTERIOR = Path(__file__).parent / "scenes" / "legacy_interior"


@pytest.fixture(scope="module")
def interior(mi: ModuleType, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A job on a copy of the interior, its 8-bit texture written beside it."""
    folder = tmp_path_factory.mktemp("legacy")
    shutil.copytree(INTERIOR, folder / "scene")
    (folder / "scene" / "textures").mkdir()
    texels = np.random.default_rng(0).integers(80, 200, (16, 16, 3), dtype=np.uint8)
    mi.Bitmap(texels).write(str(folder / "scene" / "textures" / "wood.png"))
    job = write_job(
        folder,
        render={"spp": 8, "seed": 0},
        inspection_cameras=[{"name": "objective", "objective": True}],
        channels=[{"name": "objects", "kind": "object"}],
    )
    use_scene(job, folder / "scene" / "scene.xml")
    return job


def test_every_upgrade_is_listed_with_its_line(interior: Path) -> None:
    result = sensaov("params", str(interior), "--json")
    assert result.returncode == EXIT_OK, result.stderr
    listed = json.loads(result.stdout)["scene_changes"]
    changes = {c["what"]: c["where"].rpartition(":")[2] for c in listed}
    expected = {
        "<srgb> #d8d0c0 -> <rgb> 0.686685, 0.630757, 0.527115": "41",
        "sampler 'sobol' -> 'independent'": "23",
        "film 'ldrfilm' -> 'hdrfilm'": "27",
        "hdrfilm property 'gamma' dropped": "32",
        "bitmap filter_type 'trilinear' -> 'bilinear'": "48",
        "bitmap gamma 2.2 dropped": "49",
        "bitmap filter_type 'ewa' -> 'bilinear'": "64",
        "bitmap wrap_mode_u/_v -> wrap_mode": "65",
        "conductor ext_eta '1' dropped": "75",
        "conductor ext_eta 'air' dropped": "79",
        "sunsky scale -> sun_scale and sky_scale": "162",
        "sun_radius_scale -> sun_aperture 1.0716": "163",
        "integrator 'guided_path' -> 'prb' (max_depth 5, the scene's)": "10",
    }
    assert {what: changes.get(what) for what in expected} == expected


def test_numbered_meshes_are_named_after_their_material(interior: Path) -> None:
    result = sensaov("params", str(interior), "--json")
    objects = set(json.loads(result.stdout)["objects"])
    assert {"Mesh000_Floor", "Mesh001_Walls", "Mesh003_Walls", "Mesh006_Kettle"} <= objects
    again = sensaov("params", str(interior), "--json")  # stable across runs
    assert set(json.loads(again.stdout)["objects"]) == objects


def test_the_interior_goes_through_every_step_unedited(interior: Path) -> None:
    out = interior.parent / "out"
    steps = [
        ("validate", str(interior)),
        ("run", str(interior)),
        ("project", str(interior), "--png"),
        ("rank", str(out / "buffer.npz"), "--by", "object"),
        ("sunburst", str(out / "buffer.npz"), "-o", str(out / "sunburst.svg")),
        ("report", str(interior)),
    ]
    for step in steps:
        result = sensaov(*step)
        assert result.returncode == EXIT_OK, (step, result.stderr)
    assert "Mesh001_Walls" in sensaov("rank", str(out / "buffer.npz"), "--by", "object").stdout
    assert (out / "objective.exr").is_file() and (out / "report.html").is_file()


BROKEN = """<scene version="0.5.0">
  <sensor type="perspective"><film type="hdrfilm"/></sensor>
  <shape type="obj"><string name="filename" value="models/missing.obj"/></shape>
  <shape type="sphere"><bsdf type="coating"><bsdf type="diffuse"/></bsdf></shape>
  <shape type="sphere"><bsdf type="diffuse">
    <texture type="bitmap" name="reflectance"><string name="filename" value="gone.png"/>
      <string name="channel" value="r"/></texture></bsdf></shape>
  <medium type="homogeneous" id="fog"><string name="material" value="Ketchup"/></medium>
  <blackbody name="radiance" temperature="3000"/>
</scene>"""


def test_validate_reports_every_problem_in_one_pass_without_mitsuba(tmp_path: Path) -> None:
    scene = tmp_path / "scene.xml"
    scene.write_text(BROKEN)
    job = write_job(tmp_path)
    use_scene(job, scene)
    code = (
        "import sys\n"
        "from sensaov_cli.cli import main\n"
        "try:\n    main(['validate', sys.argv[1]])\n"
        "except SystemExit as exit:\n"
        "    assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules\n"
        "    raise\n"
    )
    started = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-c", code, str(job)], capture_output=True, text=True, env=os.environ
    )
    assert time.perf_counter() - started < 10
    assert result.returncode == EXIT_BAD_INPUT, result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert "6 problems Mitsuba 3.9.1 would refuse the scene for" in line
    for problem, at in [
        ('file "models/missing.obj" not found', ":3"),
        ("has no bsdf plugin 'coating'", ":4"),
        ('file "gone.png" not found', ":6"),
        ("bitmap property 'channel' has no counterpart", ":7"),
        ("homogeneous property 'material' has no counterpart", ":8"),
        ("<blackbody> is not an element Mitsuba 3 reads", ":9"),
    ]:
        assert problem in line and f"scene.xml{at}" in line, problem


# --- the tables against Mitsuba itself -------------------------------------------------------

TEXTURE = str(Path(__file__).parents[1] / "scenes" / "cbox" / "textures" / "wall.png")
REFUSED = [
    *[(plugin, name) for plugin, names in legacy._DROPPED.items() for name in names],
    *[(plugin, name) for plugin, names in legacy._UNSUPPORTED.items() for name in names],
    ("dielectric", "int_eta"), ("roughplastic", "ext_eta"), ("conductor", "ext_eta"),
    ("bitmap", "wrap_mode_u"), ("bitmap", "gamma"), ("envmap", "gamma"),
    ("sunsky", "scale"), ("sunsky", "sun_radius_scale"), ("sunsky", "stretch"),
    ("obj", "max_smooth_angle"), ("homogeneous", "sigma_a"), ("homogeneous", "density_multiplier"),
    ("heterogeneous", "density"),
]  # fmt: skip
TARGETS = [
    ("dielectric", "int_ior"), ("bitmap", "wrap_mode"), ("bitmap", "raw"),
    ("sunsky", "sun_scale"), ("sunsky", "sky_scale"), ("sunsky", "sun_aperture"),
    ("homogeneous", "sigma_t"), ("homogeneous", "albedo"), ("homogeneous", "scale"),
]  # fmt: skip


def _loads(mi: ModuleType, plugin: str, name: str) -> bool:
    """Whether Mitsuba 3.9.1 takes property ``name`` on ``plugin`` (a minimal instance)."""
    needs = {
        "bitmap": {"filename": TEXTURE},
        "envmap": {"filename": TEXTURE},
        "obj": {"filename": str(INTERIOR / "models" / "Mesh000.obj")},
    }
    values = {"wrap_mode": "clamp", "raw": True, "collapse": True, "srgb": True, "channel": "r",
              "material": "Ketchup", "method": "woodcock", "cache": False}  # fmt: skip
    plugin_dict = {"type": plugin, **needs.get(plugin, {}), name: values.get(name, 0.5)}
    try:
        mi.load_dict(plugin_dict)
    except Exception as exc:  # Mitsuba raises plain exceptions
        assert "unreferenced" in str(exc) or "Property" in str(exc), (plugin, name, str(exc))
        return False
    return True


@pytest.mark.parametrize(("plugin", "name"), [r for r in REFUSED if r[0] != "ply"])
def test_each_old_property_upgraded_or_refused_is_one_mitsuba_refuses(
    mi: ModuleType, plugin: str, name: str
) -> None:
    assert not _loads(mi, plugin, name)


@pytest.mark.parametrize(("plugin", "name"), TARGETS)
def test_each_property_an_upgrade_writes_is_one_mitsuba_takes(
    mi: ModuleType, plugin: str, name: str
) -> None:
    assert _loads(mi, plugin, name)


def test_the_plugin_list_is_mitsubas(mi: ModuleType) -> None:
    folder = Path(mi.__file__).parent / "plugins"
    files = {path.name.split(".")[0] for path in folder.iterdir()}
    integrators = {"aov", "depth", "direct", "moment", "path", "ptracer", "stokes", "volpath",
                   "volpathmis"}  # fmt: skip
    listed = set().union(*legacy.PLUGINS.values())
    assert listed == files - integrators
