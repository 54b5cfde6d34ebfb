"""The scene as Mitsuba's parser reads it, and the rewrite, in pure XML (no Mitsuba import).

Loading the rewritten corpus scenes in Mitsuba is tests/test_corpus.py.
"""

from __future__ import annotations

import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from sensaov_cli.errors import SceneError
from sensaov_cli.job.load import load_job
from sensaov_cli.job.spec import CameraSpec, LookAt
from sensaov_cli.pipeline.validate import validate_job
from sensaov_cli.scene.expand import expand_scene
from sensaov_cli.scene.naming import name_objects
from sensaov_cli.scene.prepare import PreparedScene, prepare_xml
from sensaov_cli.scene.source import locate_load_error, write_xml

CORPUS = Path(__file__).resolve().parents[1] / "scenes" / "corpus"
SENSOR = (
    '<sensor type="perspective" id="cam"><film type="hdrfilm" id="film">'
    '<integer name="width" value="4"/><integer name="height" value="4"/></film></sensor>'
)


def write(folder: Path, name: str, body: str, version: str = "3.0.0") -> Path:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'<scene version="{version}">\n{body}\n</scene>\n')
    return path


def prepare(path: Path, shared: str = "split", **kwargs: object) -> PreparedScene:
    options: dict = {"max_depth": 4, "camera": CameraSpec(name="objective"), "resolution": None}
    options.update(kwargs)
    return prepare_xml(path, shared=shared, **options)


def parsed(prepared: PreparedScene) -> ET.Element:
    return ET.fromstring(prepared.text)


def expanded_text(path: Path, **args: str) -> str:
    return write_xml(expand_scene(path, args).root)[0]


def expand_and_name(path: Path) -> list[ET.Element]:
    root = expand_scene(path, {}).root
    name_objects(root)
    return root.findall("shape")


# --- includes -------------------------------------------------------------------------------


def test_includes_nest_and_resolve_next_to_the_including_file(tmp_path: Path) -> None:
    main = write(tmp_path, "main.xml", f'{SENSOR}\n<include filename="parts/a.xml"/>')
    write(tmp_path, "parts/a.xml", '<include filename="b.xml"/>')  # next to a.xml
    write(tmp_path, "parts/b.xml", '<shape type="sphere" id="from_b"/>')
    root = parsed(prepare(main))
    assert [s.get("id") for s in root.findall("shape")] == ["from_b"]


def test_asset_names_in_an_included_file_resolve_against_the_main_folder(tmp_path: Path) -> None:
    # Mitsuba resolves plugin file names at instantiation, against the main file's folder and
    # its <path>s, not the included file's folder (measured in 3.9.1).
    for folder in ("meshes", "parts/meshes", "assets"):
        (tmp_path / folder).mkdir(parents=True, exist_ok=True)
    (tmp_path / "meshes/m.obj").write_text("v 0 0 0\n")
    (tmp_path / "parts/meshes/m.obj").write_text("v 1 1 1\n")
    (tmp_path / "assets/t.png").write_bytes(b"png")
    main = write(tmp_path, "main.xml", '<path value="assets"/>\n<include filename="parts/a.xml"/>')
    write(
        tmp_path,
        "parts/a.xml",
        '<shape type="obj"><string name="filename" value="meshes/m.obj"/></shape>\n'
        '<bsdf type="diffuse" id="b"><texture type="bitmap" name="reflectance">'
        '<string name="filename" value="t.png"/></texture></bsdf>',
    )
    expanded = expand_scene(main, {})
    names = [el.get("value") for el in expanded.root.iter("string") if el.get("name") == "filename"]
    assert names == [str(tmp_path / "meshes/m.obj"), str(tmp_path / "assets/t.png")]
    assert tmp_path / "parts/a.xml" in expanded.files


def test_scene_root_include_keeps_objects_and_object_root_include_takes_the_name(
    tmp_path: Path,
) -> None:
    main = write(
        tmp_path,
        "main.xml",
        '<include filename="objs.xml"/>\n'
        '<shape type="sphere" id="s"><include filename="coat.xml" name="bsdf"/></shape>',
    )
    write(tmp_path, "objs.xml", '<float name="dropped" value="1"/><bsdf type="diffuse" id="d"/>')
    (tmp_path / "coat.xml").write_text('<bsdf version="3.0.0" type="plastic" id="coat"/>')
    root = expand_scene(main, {}).root
    assert [child.tag for child in root] == ["bsdf", "shape"]
    assert '<bsdf type="plastic" id="coat" name="bsdf"/>' in expanded_text(main)


def test_include_cycle_is_refused_at_the_include(tmp_path: Path) -> None:
    main = write(tmp_path, "main.xml", '<include filename="a.xml"/>')
    write(tmp_path, "a.xml", '<include filename="b.xml"/>')
    b = write(tmp_path, "b.xml", '\n<include filename="a.xml"/>')
    with pytest.raises(SceneError, match=r"include cycle: a\.xml -> b\.xml -> a\.xml") as info:
        expand_scene(main, {})
    assert info.value.where == f"{b}:3"


def test_include_depth_is_limited_as_in_mitsuba(tmp_path: Path) -> None:
    for depth in range(16):
        write(tmp_path, f"f{depth}.xml", f'<include filename="f{depth + 1}.xml"/>')
    write(tmp_path, "f16.xml", "")
    with pytest.raises(SceneError, match="limit of 15"):
        expand_scene(tmp_path / "f0.xml", {})
    write(tmp_path, "f14.xml", "")  # 14 nested includes below the main file are fine
    expand_scene(tmp_path / "f0.xml", {})


def test_missing_include_names_the_folders_searched(tmp_path: Path) -> None:
    main = write(tmp_path, "main.xml", '<include filename="nope.xml"/>')
    with pytest.raises(SceneError, match='included file "nope.xml" not found') as info:
        expand_scene(main, {})
    assert info.value.where == f"{main}:2" and str(tmp_path) in str(info.value.hint)


# --- $name arguments ------------------------------------------------------------------------


def test_argument_without_default_names_itself_file_line_and_the_job_key(tmp_path: Path) -> None:
    main = write(tmp_path, "main.xml", '<include filename="glass.xml"/>')
    glass = write(
        tmp_path,
        "glass.xml",
        '\n<bsdf type="dielectric">\n<float name="int_ior" value="$ior"/></bsdf>',
    )
    with pytest.raises(SceneError, match=r"scene argument \$ior has no value") as info:
        expand_scene(main, {})
    assert info.value.where == f"{glass}:4"
    assert "scene_args: {ior:" in str(info.value.hint)


def test_arguments_follow_mitsubas_substitution_rules(tmp_path: Path) -> None:
    main = write(
        tmp_path,
        "main.xml",
        '<default name="a" value="0.3"/><default name="spp" value="8"/>\n'
        '<include filename="inc.xml"/>\n'
        '<bsdf type="diffuse" id="d"><float name="x" value="$a5"/><float name="y" value="$leak"/>'
        '<string name="z" value="\\$a"/><integer name="n" value="$spp"/></bsdf>',
    )
    write(tmp_path, "inc.xml", '<default name="leak" value="7"/>')  # defaults leak out
    values = {
        el.get("name"): el.get("value") for el in expand_scene(main, {"spp": "2"}).root.iter()
    }
    # plain substring replacement ($a5 -> 0.35), job arguments win over defaults, \$ escapes
    assert (values["x"], values["y"], values["z"], values["n"]) == ("0.35", "7", "$a", "2")
    assert 'value="\\$a"' in expanded_text(main)  # escaped again for Mitsuba's own pass


def test_arguments_are_recorded_with_their_origin(tmp_path: Path) -> None:
    main = write(
        tmp_path, "main.xml", f'<default name="res" value="8"/>\n{SENSOR}'.replace('"4"', '"$res"')
    )
    given = expand_scene(main, {"res": "16"}).arguments["res"]
    assert (given.value, given.origin) == ("16", "job")
    defaults = expand_scene(main, {}).arguments["res"]
    assert (defaults.value, defaults.origin) == ("8", f"{main}:2")
    assert prepare(main, scene_args={"res": "16"}).scene_args == {"res": "16"}
    assert prepare(main).scene_args == {"res": "8"}


def test_an_argument_the_scene_does_not_use_is_refused(tmp_path: Path) -> None:
    main = write(tmp_path, "main.xml", '<default name="spp" value="4"/>')
    with pytest.raises(SceneError, match="scene argument 'spp' is not used"):
        expand_scene(main, {"spp": "16"})


def test_alias_is_resolved_and_must_follow_its_source(tmp_path: Path) -> None:
    main = write(
        tmp_path,
        "main.xml",
        '<bsdf type="diffuse" id="red"/><alias id="red" as="crimson"/>'
        '<shape type="sphere" id="s"><ref id="crimson"/></shape>',
    )
    assert expand_scene(main, {}).root.find("shape/ref").get("id") == "red"  # type: ignore[union-attr]
    early = write(
        tmp_path, "early.xml", '<alias id="red" as="crimson"/><bsdf type="diffuse" id="red"/>'
    )
    with pytest.raises(SceneError, match='alias source id "red" not found'):
        expand_scene(early, {})


def test_duplicate_ids_across_files_name_both_places(tmp_path: Path) -> None:
    main = write(tmp_path, "main.xml", '<bsdf type="diffuse" id="b"/>\n<include filename="i.xml"/>')
    write(tmp_path, "i.xml", '<bsdf type="diffuse" id="b"/>')
    with pytest.raises(
        SceneError, match=f"duplicate id 'b' \\(first defined at {re.escape(str(main))}:2\\)"
    ):
        expand_scene(main, {})


def test_old_format_files_are_upgraded_per_file(tmp_path: Path) -> None:
    main = write(tmp_path, "main.xml", '<include filename="old.xml"/>')
    write(
        tmp_path,
        "old.xml",
        '<bsdf type="diffuse" id="d"><texture type="checkerboard" name="diffuseReflectance">'
        '<float name="uscale" value="4"/></texture></bsdf>',
        version="0.6.0",
    )
    text = expanded_text(main)
    assert 'name="reflectance"' in text and '<scale x="4"/>' in text and "uscale" not in text


def test_malformed_included_file_names_its_own_file_and_line(tmp_path: Path) -> None:
    main = write(tmp_path, "main.xml", '<include filename="bad.xml"/>')
    bad = tmp_path / "bad.xml"
    bad.write_text('<scene version="3.0.0">\n<shape type="sphere">\n</scene>\n')
    with pytest.raises(SceneError, match="malformed XML") as info:
        expand_scene(main, {})
    assert info.value.where == f"{bad}:3"


# --- the rewrite ----------------------------------------------------------------------------


def test_every_line_of_the_rewritten_text_points_at_the_users_file(tmp_path: Path) -> None:
    main = write(tmp_path, "main.xml", f'{SENSOR}\n<include filename="s.xml"/>')
    inc = write(
        tmp_path,
        "s.xml",
        '\n<shape type="sphere" id="ball">\n<float name="radius" value="x"/></shape>',
    )
    prepared = prepare(main)
    line = next(i for i, text in enumerate(prepared.text.splitlines(), 1) if 'value="x"' in text)
    error = f'[parser.cpp:451] Error while loading string (line {line}, col 9): could not parse "x"'
    assert locate_load_error(error, prepared.line_sources) == ('could not parse "x"', f"{inc}:4")


def test_a_long_value_in_mitsubas_error_is_shortened() -> None:
    error = (
        f'Error while loading string (line 1, col 2): could not parse integer value "{"9" * 5000}"'
    )
    message, found = locate_load_error(error, ("f.xml:1",))
    assert message == f'could not parse integer value "{"9" * 60}…"' and found == "f.xml:1"


def test_copied_sensors_carry_no_ids_of_their_own(tmp_path: Path) -> None:
    sampler = '<sampler type="independent" id="smp"/>'
    main = write(tmp_path, "main.xml", SENSOR.replace("</sensor>", f"{sampler}</sensor>"))
    cameras = (
        CameraSpec(name="objective", objective=True, resolution=(2, 2)),
        CameraSpec(name="same", sensor="cam"),
    )
    root = parsed(prepare(main, inspection=cameras, resolution=(8, 8)))
    ids = [el.get("id") for el in root.iter() if el.get("id")]
    assert len(ids) == len(set(ids)) and ids.count("film") == 1 and ids.count("smp") == 1


def test_a_film_shared_by_ref_is_copied_before_it_is_resized(tmp_path: Path) -> None:
    film = '<film type="hdrfilm" id="F"><integer name="width" value="4"/></film>'
    sensors = "".join(f'<sensor type="perspective" id="{i}"><ref id="F"/></sensor>' for i in "ab")
    main = write(tmp_path, "main.xml", film + sensors)
    root = parsed(prepare(main, resolution=(8, 6)))
    widths = {s.get("id"): s.find("film/integer[@name='width']") for s in root.findall("sensor")}
    assert widths["a"].get("value") == "8" and widths["b"] is None  # type: ignore[union-attr]
    assert root.find("film").find("integer").get("value") == "4"  # type: ignore[union-attr]


def test_a_sensor_with_a_refd_film_can_be_copied_for_every_kind_of_camera(tmp_path: Path) -> None:
    # Review item 5: the copy used to strip the <ref>'s id, and Mitsuba refused the <ref>.
    film = '<film type="hdrfilm" id="film"><integer name="width" value="4"/></film>'
    sampler = '<sampler type="independent" id="smp"/>'
    sensors = "".join(
        f'<sensor type="perspective" id="{i}"><ref id="film"/><ref id="smp"/></sensor>'
        for i in ("a", "b")
    )
    main = write(tmp_path, "main.xml", film + sampler + sensors)
    look = LookAt(origin=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    cameras = (
        CameraSpec(name="objective", objective=True),
        CameraSpec(name="other", sensor="b", resolution=(6, 2)),
        CameraSpec(name="look", look_at=look, resolution=(3, 3)),
    )
    root = parsed(prepare(main, inspection=cameras))
    assert all(ref.get("id") for ref in root.iter("ref"))
    ids = [el.get("id") for el in root.iter() if el.get("id") and el.tag != "ref"]
    assert len(ids) == len(set(ids))
    sizes = {
        s.get("id"): {i.get("name"): i.get("value") for i in s.findall("film/integer")}
        for s in root.findall("sensor")
    }
    assert sizes["sensaov_inspect_objective"] == {"width": "4"}  # a copy of the shared film
    assert sizes["sensaov_inspect_other"] == {"width": "6", "height": "2"}
    assert sizes["sensaov_inspect_look"] == {"width": "3", "height": "3"}
    assert sizes["a"] == sizes["b"] == {}  # the scene's own sensors still share "film"


def test_a_resized_film_loses_its_crop_window(tmp_path: Path) -> None:
    # Review item 8: a crop window overrode the size an inspection camera or the job asked for.
    crop = "".join(
        f'<integer name="{n}" value="{v}"/>'
        for n, v in (("width", 32), ("height", 32), ("crop_offset_x", 8), ("crop_width", 16))
    )
    sensor = f'<sensor type="perspective" id="cam"><film type="hdrfilm">{crop}</film></sensor>'
    main = write(tmp_path, "main.xml", sensor)
    look = LookAt(origin=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    cameras = (
        CameraSpec(name="same", sensor="cam", resolution=(48, 48)),
        CameraSpec(name="look", look_at=look, resolution=(40, 40)),
    )
    kept = parsed(prepare(main, inspection=cameras)).find("sensor[@id='cam']/film")
    assert kept is not None and len(kept.findall("integer")) == 4  # not resized: as written
    root = parsed(prepare(main, inspection=cameras, resolution=(20, 20)))
    for sensor_element in root.findall("sensor"):
        names = [i.get("name") for i in sensor_element.findall("film/integer")]
        assert names == ["width", "height"], sensor_element.get("id")


def test_a_film_larger_than_a_job_may_ask_for_is_refused(tmp_path: Path) -> None:
    film = '<film type="hdrfilm"><integer name="width" value="$res"/></film>'
    main = write(tmp_path, "main.xml", f"\n<sensor type='perspective'>{film}</sensor>")
    with pytest.raises(SceneError, match="film width 99999 is larger than 16384") as info:
        prepare(main, scene_args={"res": "99999"})
    assert info.value.where == f"{main}:3"
    prepare(main, scene_args={"res": "99999"}, resolution=(8, 8))  # the job's size wins
    look = LookAt(origin=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    with pytest.raises(SceneError, match="inspection camera 'same'"):
        prepare(
            main,
            scene_args={"res": "99999"},
            camera=CameraSpec(name="objective", look_at=look),
            inspection=(CameraSpec(name="same", objective=False, sensor=None),),
        )


def test_a_huge_name_is_a_scene_error_with_the_name_shortened(tmp_path: Path) -> None:
    # Review item 6: the OS refused the name ("File name too long") as an internal error.
    texture = '<texture type="bitmap" name="reflectance"><string name="filename" value="$tex"/>'
    shape = f'<shape type="sphere"><bsdf type="diffuse">{texture}</texture></bsdf></shape>'
    main = write(tmp_path, "main.xml", f"{SENSOR}\n{shape}")
    with pytest.raises(SceneError) as info:
        prepare(main, scene_args={"tex": "x" * 200_000 + ".png"})
    assert info.value.where == f"{main}:3" and len(str(info.value)) < 400
    assert "…" in str(info.value)


def test_files_the_scene_reads_must_exist(tmp_path: Path) -> None:
    # Review item 9: validate said ok, and run failed in Mitsuba.
    mesh = '<shape type="obj"><string name="filename" value="meshes/nothere.obj"/></shape>'
    main = write(tmp_path, "main.xml", f'{SENSOR}\n<include filename="sub/objs.xml"/>')
    write(tmp_path, "sub/objs.xml", f"\n{mesh}")
    with pytest.raises(SceneError, match='file "meshes/nothere.obj" not found') as info:
        prepare(main)
    assert info.value.where == f"{tmp_path / 'sub/objs.xml'}:3"
    spectrum = '<bsdf type="diffuse" id="b"><spectrum name="reflectance" filename="r.spd"/></bsdf>'
    with pytest.raises(SceneError, match='file "r.spd" not found'):
        prepare(write(tmp_path, "spd.xml", f"{SENSOR}\n{spectrum}"))


def test_elements_mitsuba_does_not_read_are_refused_at_their_line(tmp_path: Path) -> None:
    old = '<shapegroup id="g"><shape type="sphere"/></shapegroup>'
    main = write(tmp_path, "main.xml", f"{SENSOR}\n\n{old}")
    with pytest.raises(SceneError, match=r"<shapegroup> is not an element") as info:
        prepare(main)
    assert info.value.where == f"{main}:4" and 'type="shapegroup"' in str(info.value)
    with pytest.raises(SceneError, match=r"<colour> is not an element"):
        prepare(write(tmp_path, "c.xml", f'{SENSOR}<bsdf type="diffuse"><colour/></bsdf>'))


def test_validate_refuses_what_the_preparation_refuses(tmp_path: Path) -> None:
    # validate prepares the scene as run does, every camera placed: it refuses what run would.
    film = '<film type="hdrfilm"><integer name="width" value="$res"/></film>'
    main = write(tmp_path, "main.xml", f'<sensor type="perspective" id="cam">{film}</sensor>')
    job = tmp_path / "job.yaml"
    job.write_text(
        f"version: 1\nscene: {main}\nscene_args: {{res: 99999}}\n"
        "objectives: [{name: luma, type: mean_luminance}]\noutput: out\n"
    )
    with pytest.raises(SceneError, match="larger than 16384"):
        validate_job(load_job(job))
    job.write_text(job.read_text().replace("99999", "16"))
    assert validate_job(load_job(job)).sensor_ids == ("cam",)


def test_split_gives_each_instance_its_own_shapegroup() -> None:
    # Review item 4: instances shared their group's parameters, so each got the whole gradient.
    prepared = prepare(CORPUS / "instanced_shelf" / "scene.xml", shared="split")
    assert prepared.instances == {
        "pot_a": "pot_group_pot_a",
        "pot_b": "pot_group_pot_b",
        "pot_group_2": "pot_group_pot_group_2",
    }
    assert prepared.shapegroups["pot_group_pot_b"] == ("blob_pot_b", "lid_sphere_pot_b")
    assert set(prepared.shapegroups) == set(prepared.instances.values())
    assert prepared.materials["blob_pot_a"] == "pot_glaze"
    assert prepared.materials["pot_b"] == "pot_glaze+lid_mat"
    assert prepared.split["lid_mat"] == (
        "lid_sphere_pot_a",
        "lid_sphere_pot_b",
        "lid_sphere_pot_group_2",
    )
    root = parsed(prepared)
    assert root.find("shape[@id='pot_group']") is None
    ids = [el.get("id") for el in root.iter() if el.get("id") and el.tag != "ref"]
    assert len(ids) == len(set(ids))


def test_a_latin_1_file_without_a_declaration_is_read_as_mitsuba_reads_it(
    tmp_path: Path,
) -> None:
    # Review item 10: Mitsuba loads it; sensaov said "not well-formed (invalid token)".
    main = write(tmp_path, "main.xml", f'{SENSOR}<include filename="objs.xml"/>')
    body = '<scene version="3.0.0">\n<!-- Matériau créé par Günther -->\n<shape type="sphere"/>'
    (tmp_path / "objs.xml").write_bytes((body + "</scene>\n").encode("latin-1"))
    assert [s.get("type") for s in parsed(prepare(main)).findall("shape")] == ["sphere"]
    (tmp_path / "objs.xml").write_bytes(b"<scene version='3.0.0'>\n<shape type='sphere'>\n")
    with pytest.raises(SceneError, match="malformed XML"):
        prepare(main)


def test_unnamed_objects_get_names_from_what_the_scene_says() -> None:
    names = {
        scene: tuple(
            s.get("id")
            for s in parsed(prepare(CORPUS / scene / "scene.xml", shared="keep")).iter("shape")
        )
        for scene in ("cbox_spectral", "instanced_shelf", "emitter_zoo")
    }
    assert {"box", "white_rectangle", "white_rectangle_1"} <= set(names["cbox_spectral"])
    assert {"blob", "lid_sphere", "pot_group_2", "wall_rectangle"} <= set(names["instanced_shelf"])
    assert {"strip_light", "stage_white_rectangle"} <= set(names["emitter_zoo"])
    zoo = parsed(prepare(CORPUS / "emitter_zoo" / "scene.xml"))
    assert [e.get("id") for e in zoo.findall("emitter")] == [
        "point_light",
        "spot",
        "sun",
        "ambient",
    ]


def test_generated_names_never_take_a_users_id(tmp_path: Path) -> None:
    for folder in ("m", "n"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "blob.ply").write_bytes(b"ply")
    main = write(
        tmp_path,
        "main.xml",
        '<shape type="sphere" id="blob"/>'
        '<shape type="ply"><string name="filename" value="m/blob.ply"/></shape>'
        '<shape type="ply"><string name="filename" value="n/blob.ply"/></shape>',
    )
    assert [s.get("id") for s in expand_and_name(main)] == ["blob", "blob_1", "blob_2"]


def test_names_are_the_same_on_every_preparation() -> None:
    scene = CORPUS / "instanced_shelf" / "scene.xml"
    assert prepare(scene).text == prepare(scene).text


def test_instances_shapegroups_and_their_materials() -> None:
    prepared = prepare(CORPUS / "instanced_shelf" / "scene.xml", shared="keep")
    assert prepared.instances == {
        "pot_a": "pot_group",
        "pot_b": "pot_group",
        "pot_group_2": "pot_group",
    }
    assert prepared.shapegroups == {"pot_group": ("blob", "lid_sphere")}
    assert prepared.materials["pot_b"] == "pot_glaze+lid_mat"
    assert (
        prepared.materials["lid_sphere"] == "lid_mat" and prepared.materials["floor"] == "floor_mat"
    )


def test_top_level_textures_are_written_where_they_are_used() -> None:
    scene = CORPUS / "texture_lab" / "scene.xml"
    split = prepare(scene)
    assert split.textures == {
        "glyph_repeat": ("tile_repeat_mat.reflectance",),
        "floor_checks": ("floor_mat.reflectance",),
    }
    texture = parsed(split).find("bsdf[@id='tile_repeat_mat']/texture")
    assert (
        texture is not None and texture.get("name") == "reflectance" and "id" not in texture.attrib
    )
    kept = parsed(prepare(scene, shared="keep")).find("bsdf[@id='floor_mat']/texture")
    assert kept is not None and kept.get("id") == "floor_checks"


def test_a_texture_used_twice_gets_a_copy_per_use_or_stays_shared(tmp_path: Path) -> None:
    main = write(
        tmp_path,
        "main.xml",
        '<texture type="checkerboard" id="t"/>'
        '<bsdf type="diffuse" id="a"><ref name="reflectance" id="t"/></bsdf>'
        '<bsdf type="diffuse" id="b"><ref name="reflectance" id="t"/></bsdf>' + SENSOR,
    )
    split = parsed(prepare(main))
    assert len(split.findall("bsdf/texture")) == 2 and not split.findall(".//ref")
    kept = parsed(prepare(main, shared="keep"))
    assert kept.find("bsdf[@id='a']/texture").get("id") == "t"  # type: ignore[union-attr]
    assert kept.find("bsdf[@id='b']/ref").get("id") == "t"  # type: ignore[union-attr]


def test_nested_bitmaps_load_as_float_and_envmaps_are_left_alone() -> None:
    root = parsed(prepare(CORPUS / "texture_lab" / "scene.xml"))
    nested = root.find("bsdf[@id='nested_mat']/texture/texture")
    assert nested is not None and nested.find("string[@name='format']").get("value") == "variant"  # type: ignore[union-attr]
    sky = parsed(prepare(CORPUS / "glass_table" / "scene.xml", scene_args={"ior": "1.5"}))
    assert sky.find("emitter[@id='sky']/string[@name='format']") is None


# --- sensors and fingerprint ---------------------------------------------------------------


def test_sensor_ids_follow_includes_without_mitsuba() -> None:
    assert prepare(CORPUS / "shaderball" / "scene.xml").sensor_ids == ("Camera-camera",)
    glass = prepare(CORPUS / "glass_table" / "scene.xml", scene_args={"ior": "1.5"})
    assert glass.sensor_ids == ("camera",)


def test_fingerprint_covers_included_files_meshes_and_arguments(tmp_path: Path) -> None:
    (tmp_path / "m.obj").write_text("v 0 0 0\n")
    main = write(
        tmp_path, "main.xml", f'<default name="r" value="1"/><include filename="i.xml"/>{SENSOR}'
    )
    inc = write(
        tmp_path,
        "i.xml",
        '<shape type="obj"><string name="filename" value="m.obj"/>'
        '<float name="x" value="$r"/></shape>',
    )
    first = prepare(main).fingerprint
    assert prepare(main).fingerprint == first
    inc.write_text(inc.read_text().replace('obj">', 'obj"> '))
    second = prepare(main).fingerprint
    (tmp_path / "m.obj").write_text("v 0 0 1\n")
    third = prepare(main).fingerprint
    argued = prepare(main, scene_args={"r": "2"}).fingerprint
    assert len({first, second, third, argued}) == 4


def test_validate_needs_no_renderer() -> None:
    """``validate`` prepares the scene and checks every camera: it must not load Mitsuba."""
    job = CORPUS.parents[1] / "configs" / "cbox.yaml"
    code = (
        "import sys; from pathlib import Path\n"
        "from sensaov_cli.pipeline.validate import validate_job\n"
        "from sensaov_cli.job.load import load_job\n"
        f"assert validate_job(load_job(Path({str(job)!r}))).sensor_ids\n"
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'mitsuba', 'drjit'}))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == "[]"
