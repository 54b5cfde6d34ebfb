"""Every emitter, BSDF and texture plugin of Mitsuba 3.9.1, instantiated in a tiny scene: a
read-only or non-differentiable entry is left out with its reason, and every parameter sensaov
selects takes a gradient-enabled leaf of its own (what a backward pass does first) without an
error (a sunsky's read-only ``sun_direction`` once crashed ``run`` after the primal).
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from sensaov_cli.job.spec import CameraSpec, ParameterSpec
from sensaov_cli.render.adjoint import enable_gradients
from sensaov_cli.render.loading import load_scene
from sensaov_cli.scene.legacy import PLUGINS
from sensaov_cli.scene.prepare import prepare_xml

DIFFUSE = '<bsdf type="diffuse"/>'
BITMAP = '<texture type="bitmap" name="{}"><string name="filename" value="tex.exr"/></texture>'
# What each plugin needs to be instantiated at all (its required properties and children).
NEEDS = {
    "blendbsdf": f'<float name="weight" value="0.3"/>{DIFFUSE}<bsdf type="conductor"/>',
    "bumpmap": BITMAP.format("bump") + DIFFUSE,
    "normalmap": BITMAP.format("normalmap") + '<bsdf type="roughconductor"/>',
    "mask": f'<float name="opacity" value="0.5"/>{DIFFUSE}',
    "twosided": DIFFUSE,
    "envmap": '<string name="filename" value="sky.exr"/>',
    "projector": '<float name="fov" value="30"/>',
    "spot": '<rgb name="intensity" value="4"/>',
    "bitmap": '<string name="filename" value="tex.exr"/>',
    "mesh_attribute": '<string name="name" value="vertex_color"/>',
    "volume": '<volume type="constvolume" name="volume"><float name="value" value="0.5"/></volume>',
    "blackbody": '<float name="temperature" value="3000"/>',
    "irregular": '<string name="wavelengths" value="400, 700"/>'
    '<string name="values" value="0.5, 0.8"/>',
    "regular": '<float name="wavelength_min" value="400"/>'
    '<float name="wavelength_max" value="700"/><string name="values" value="0.5, 0.8"/>',
    "rawconstant": '<float name="value" value="0.5"/>',
    "srgb": '<rgb name="color" value="0.5, 0.4, 0.3"/>',
    "uniform": '<float name="value" value="0.5"/>',
}
# Plugins that cannot be instantiated in an RGB variant from files we can write here.
NOT_HERE = {
    "measured": "needs a measured BRDF file from the RGL database",
    "measured_polarized": "spectral variants only",
}
SHAPED_EMITTERS = ("area", "directionalarea")  # emitters that live on a shape
SCENE = """<scene version="3.0.0">
  <sensor type="perspective" id="camera">
    <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
  </sensor>
  {body}
</scene>"""
MESH = """ply
format ascii 1.0
element vertex 3
property float x
property float y
property float z
property float u
property float v
property uchar red
property uchar green
property uchar blue
element face 1
property list uchar int vertex_indices
end_header
-1 -1 0 0 0 255 0 0
1 -1 0 1 0 0 255 0
0 1 0 0.5 1 0 0 255
3 0 1 2
"""


def body(tag: str, plugin: str) -> str:
    inner = NEEDS.get(plugin, "")
    if tag == "bsdf":
        return (
            f'<shape type="sphere" id="object"><bsdf type="{plugin}">{inner}</bsdf></shape>'
            '<emitter type="constant" id="sky"/>'
        )
    if tag == "emitter" and plugin in SHAPED_EMITTERS:
        return (
            f'<shape type="rectangle" id="lamp"><emitter type="{plugin}">{inner}</emitter></shape>'
        )
    if tag == "emitter":
        return (
            f'<emitter type="{plugin}" id="lamp">{inner}</emitter><shape type="sphere" id="ball"/>'
        )
    shape = '<shape type="ply" id="object"><string name="filename" value="mesh.ply"/>'
    return (
        f'{shape}<bsdf type="diffuse"><texture type="{plugin}" name="reflectance">{inner}'
        '</texture></bsdf></shape><emitter type="constant" id="sky"/>'
    )


CASES = [
    (tag, plugin)
    for tag in ("bsdf", "emitter", "texture")
    for plugin in sorted(PLUGINS[tag] - NOT_HERE.keys())
]


def test_only_the_plugins_named_with_a_reason_are_left_out_of_the_sweep() -> None:
    assert NOT_HERE.keys() <= PLUGINS["bsdf"], "a plugin left out that Mitsuba no longer has"
    assert len(CASES) == sum(len(PLUGINS[tag]) for tag in ("bsdf", "emitter", "texture")) - 2


@pytest.fixture(scope="module")
def folder(mi: ModuleType, tmp_path_factory: pytest.TempPathFactory) -> Path:
    where = tmp_path_factory.mktemp("plugins")
    rng = np.random.default_rng(0)
    mi.Bitmap(0.2 + 0.6 * rng.random((8, 8, 3), dtype=np.float32)).write(str(where / "tex.exr"))
    mi.Bitmap(0.5 + rng.random((8, 16, 3), dtype=np.float32)).write(str(where / "sky.exr"))
    (where / "mesh.ply").write_text(MESH)
    return where


@pytest.mark.parametrize(("tag", "plugin"), CASES)
def test_every_plugin_gives_its_parameters_leaves_or_a_reason(
    mi: ModuleType, folder: Path, tag: str, plugin: str
) -> None:
    scene = folder / f"{tag}_{plugin}.xml"
    scene.write_text(SCENE.format(body=body(tag, plugin)))
    prepared = prepare_xml(
        scene, max_depth=3, camera=CameraSpec("objective"), resolution=None, shared="split"
    )
    loaded = load_scene(prepared, variant="llvm_ad_rgb", parameters=ParameterSpec())
    reasons = {item.key: item.reason for item in loaded.excluded}
    for key in loaded.params.keys():
        flags = loaded.params.properties[key][3]
        if flags & int(mi.ParamFlags.ReadOnly):
            assert reasons[key].startswith("read-only"), (key, reasons.get(key))
        if flags & int(mi.ParamFlags.NonDifferentiable):
            assert key in reasons, key
    enable_gradients(loaded)  # every selected parameter: a leaf, assigned, update(): no error
    enable_gradients(loaded, set())


def test_the_sweep_found_the_sunskys_read_only_direction(mi: ModuleType, folder: Path) -> None:
    scene = folder / "sunsky.xml"
    scene.write_text(SCENE.format(body=body("emitter", "sunsky")))
    prepared = prepare_xml(
        scene, max_depth=3, camera=CameraSpec("objective"), resolution=None, shared="split"
    )
    loaded = load_scene(prepared, variant="llvm_ad_rgb", parameters=ParameterSpec())
    reasons = {item.key: item.reason for item in loaded.excluded}
    assert reasons["lamp.sun_direction"].startswith("read-only")


def test_the_sweep_covers_every_plugin_mitsuba_ships(mi: ModuleType) -> None:
    """The plugin list the sweep (and validate) use is Mitsuba's own plugins folder, by type."""
    folder = Path(mi.__file__).parent / "plugins"
    manager = mi.PluginManager.instance()
    kinds = {"bsdf": mi.ObjectType.BSDF, "emitter": mi.ObjectType.Emitter}
    kinds |= {"texture": mi.ObjectType.Texture, "medium": mi.ObjectType.Medium}
    shipped = {tag: set() for tag in kinds}
    for library in folder.glob("*.so"):
        kind = manager.plugin_type(library.stem)
        shipped.update({tag: found | {library.stem} for tag, found in shipped.items()
                        if kinds[tag] == kind})  # fmt: skip
    assert shipped == {tag: set(PLUGINS[tag]) for tag in kinds}
