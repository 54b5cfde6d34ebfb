"""The job spec: parsing, defaults, schema, hashing, and where each malformed file points."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from sensaov_cli.errors import EXIT_BAD_INPUT, SpecError
from sensaov_cli.job.load import SUPPORTED_VERSIONS, job_schema, load_job
from sensaov_cli.job.spec import (
    CameraSpec,
    ChannelSpec,
    JobSpec,
    LookAt,
    ObjectiveSpec,
    ParameterSpec,
    RenderSpec,
)

from .spec_cases import CASE_PARAMS, SpecCase, expected_where, write_fixture

FULL_JOB = """\
version: 1
scene: scene.xml
variant: llvm_ad_rgb
render:
  spp: 8
  max_depth: -1
  seed: 3
  resolution: [64, 48]
parameters:
  include: "*.reflectance.*"
  exclude: ["*.emitter.*"]
  shared: keep
objective_camera: {look_at: {origin: [0, 1, 5], target: [0, 1, 0], up: [0, 1, 0]}, fov: 35}
objectives:
  - name: mean_luma
    type: mean_luminance
  - name: centre
    type: region_luminance
    region: [0.25, 0.25, 0.75, 0.75]
  - name: masked
    type: region_luminance
    mask: mask.exr
  - name: match
    type: l2_to_target
    target: target.exr
  - name: custom
    type: python
    function: "mymodule:objective"
    path: pydir
inspection_cameras:
  - name: overhead
    look_at: {origin: [0, 3, 3], target: [0, 0, 0], up: [0, 1, 0]}
  - name: side
    sensor: sensor2
    vis_spp: 4
  - name: objective
    objective: true
    resolution: [32, 32]
channels:
  - name: objects
    kind: object
  - name: rough
    kind: type
    types: [roughness]
    aggregate: rms
  - name: refl
    kind: select
    select: "*.reflectance.*"
    weight: raw
    sign: magnitude
    tonemap: symlog
    normalize: shared
output: ../out/cbox
"""

MINIMAL_JOB = """\
version: 1
scene: scene.xml
objectives:
  - name: luma
    type: mean_luminance
"""


def expected_full_job(root: Path) -> JobSpec:
    overhead = LookAt((0.0, 3.0, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    return JobSpec(
        path=root / "job.yaml",
        version=1,
        scene=root / "scene.xml",
        variant="llvm_ad_rgb",
        render=RenderSpec(spp=8, max_depth=-1, seed=3, resolution=(64, 48)),
        parameters=ParameterSpec(("*.reflectance.*",), ("*.emitter.*",), "keep"),
        objective_camera=CameraSpec(
            "objective", look_at=LookAt((0.0, 1.0, 5.0), (0.0, 1.0, 0.0), (0.0, 1.0, 0.0)), fov=35.0
        ),
        objectives=(
            ObjectiveSpec("mean_luma", "mean_luminance"),
            ObjectiveSpec("centre", "region_luminance", region=(0.25, 0.25, 0.75, 0.75)),
            ObjectiveSpec("masked", "region_luminance", mask=root / "mask.exr"),
            ObjectiveSpec("match", "l2_to_target", target=root / "target.exr"),
            ObjectiveSpec("custom", "python", function="mymodule:objective", path=root / "pydir"),
        ),
        inspection_cameras=(
            CameraSpec("overhead", look_at=overhead, resolution=(256, 256)),
            CameraSpec("side", sensor="sensor2", vis_spp=4),
            CameraSpec("objective", resolution=(32, 32), objective=True),
        ),
        channels=(
            ChannelSpec("objects", "object"),
            ChannelSpec("rough", "type", types=("roughness",), aggregate="rms"),
            ChannelSpec(
                "refl",
                "select",
                select="*.reflectance.*",
                weight="raw",
                sign="magnitude",
                tonemap="symlog",
                normalize="shared",
            ),
        ),
        output=root.parent / "out" / "cbox",
    )


def test_full_job_parses_to_the_expected_dataclasses(tmp_path: Path) -> None:
    job = write_fixture(tmp_path, FULL_JOB)
    assert load_job(job) == expected_full_job(tmp_path)


def test_defaults(tmp_path: Path) -> None:
    spec = load_job(write_fixture(tmp_path, MINIMAL_JOB))
    assert spec.variant == "auto"
    assert spec.render == RenderSpec(spp=64, max_depth=None, seed=0, resolution=None)
    assert spec.render == RenderSpec()
    assert spec.parameters == ParameterSpec(("*",), (), "split") == ParameterSpec()
    assert spec.objective_camera == CameraSpec("objective")
    assert spec.inspection_cameras == ()
    assert [(c.name, c.kind, c.types, c.select) for c in spec.channels] == [
        ("objects", "object", None, None),
        ("types", "type", None, None),
    ]
    assert {(c.weight, c.sign, c.aggregate, c.tonemap, c.normalize) for c in spec.channels} == {
        ("value", "signed", "sum", "none", "none")  # sum: the one default score
    }
    assert spec.output == tmp_path / "out" / "job"
    assert SUPPORTED_VERSIONS == (1,)


def test_sensor_objective_camera_and_python_path_default(tmp_path: Path) -> None:
    text = MINIMAL_JOB.replace("objectives:", "objective_camera: sensor2\nobjectives:")
    text += "  - name: mine\n    type: python\n    function: pkg.mod:fn\n"
    spec = load_job(write_fixture(tmp_path, text))
    assert spec.objective_camera == CameraSpec("objective", sensor="sensor2")
    assert spec.objectives[1].path == tmp_path
    assert spec.objectives[1].definition() == {
        "name": "mine",
        "type": "python",
        "function": "pkg.mod:fn",
        "path": str(tmp_path),
    }


def test_specs_are_frozen(tmp_path: Path) -> None:
    spec = load_job(write_fixture(tmp_path, MINIMAL_JOB))
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.render.spp = 1  # type: ignore[misc]


def test_a_spec_built_in_code_keeps_the_checks_of_a_job_file() -> None:
    with pytest.raises(ValueError, match="target must differ from origin"):
        LookAt((1.0, 2.0, 3.0), (1.0, 2.0, 3.0), (0.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="exactly one of region or mask"):
        ObjectiveSpec("centre", "region_luminance")


def test_to_dict_is_canonical_json(tmp_path: Path) -> None:
    spec = load_job(write_fixture(tmp_path, FULL_JOB))
    data = spec.to_dict()
    assert json.loads(json.dumps(data)) == data
    assert data["scene"] == str(tmp_path / "scene.xml")
    assert data["objectives"][1]["region"] == [0.25, 0.25, 0.75, 0.75]
    assert spec.objectives[3].definition() == {
        "name": "match",
        "type": "l2_to_target",
        "target": str(tmp_path / "target.exr"),
    }


def test_job_hash_is_stable_and_independent_of_location(tmp_path: Path) -> None:
    first = load_job(write_fixture(tmp_path / "a", FULL_JOB, name="one.yaml"))
    second = load_job(write_fixture(tmp_path / "b" / "deeper", FULL_JOB, name="one.yaml"))
    assert first.path != second.path
    assert first.job_hash() == second.job_hash() == load_job(first.path).job_hash()
    assert len(first.job_hash()) == 64
    changed = FULL_JOB.replace("spp: 8", "spp: 9")
    other = load_job(write_fixture(tmp_path / "a", changed, name="two.yaml"))
    assert other.job_hash() != first.job_hash()


def test_schema_describes_every_top_level_key() -> None:
    schema = job_schema()
    json.dumps(schema)
    fields = [field.name for field in dataclasses.fields(JobSpec) if field.name != "path"]
    assert sorted(schema["properties"]) == sorted(fields)
    assert set(schema["required"]) == {"version", "scene", "objectives"}
    assert schema["properties"]["render"]["default"] == {}
    assert schema["additionalProperties"] is False
    import jsonschema

    validator = jsonschema.Draft202012Validator(schema)
    validator.validate(yaml.safe_load(FULL_JOB))
    validator.validate(yaml.safe_load(MINIMAL_JOB))
    bad = yaml.safe_load(MINIMAL_JOB) | {"objectivs": []}
    assert not validator.is_valid(bad)


@pytest.mark.parametrize("case", CASE_PARAMS)
def test_malformed_job_names_where(tmp_path: Path, case: SpecCase) -> None:
    job = write_fixture(tmp_path, case.text)
    with pytest.raises(SpecError) as caught:
        load_job(job)
    message = str(caught.value)
    assert message.startswith(expected_where(str(job), case) + ": "), message
    assert case.says in message
    assert "\n" not in message
    assert caught.value.exit_code == EXIT_BAD_INPUT


def test_where_names_the_job_as_given(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    write_fixture(tmp_path / "configs", MINIMAL_JOB.replace("type: mean", "typ: mean"))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SpecError, match=r"^configs/job\.yaml:5: objectives\[0\]\.typ: "):
        load_job(Path("configs/job.yaml"))


@pytest.mark.parametrize("make", ["missing", "directory"])
def test_unreadable_job_file(tmp_path: Path, make: str) -> None:
    job = tmp_path / "job.yaml"
    if make == "directory":
        job.mkdir()
    with pytest.raises(SpecError, match=f"^{re.escape(str(job))}: "):
        load_job(job)


def test_paths_are_relative_to_the_job_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    write_fixture(tmp_path / "src", FULL_JOB)
    shutil.copytree(tmp_path / "src", tmp_path / "moved")
    monkeypatch.chdir(tmp_path / "src")
    spec = load_job(Path("../moved/job.yaml"))
    assert spec.path == tmp_path / "moved" / "job.yaml"
    assert spec.scene == tmp_path / "moved" / "scene.xml"
    assert spec.objectives[2].mask == tmp_path / "moved" / "mask.exr"


def test_yaml_anchors_and_merge_keys_read_as_safe_load_does(tmp_path: Path) -> None:
    text = MINIMAL_JOB + "render:\n  <<: &base {spp: 4, seed: 2}\n  spp: 5\n"
    text += "inspection_cameras:\n  - {name: a, sensor: s, <<: &cam {vis_spp: 3}}\n"
    text += "  - {name: b, sensor: t, <<: *cam}\n"
    spec = load_job(write_fixture(tmp_path, text))
    assert (spec.render.spp, spec.render.seed) == (5, 2)
    assert [camera.vis_spp for camera in spec.inspection_cameras] == [3, 3]


@pytest.mark.parametrize(
    ("written", "value"),
    [("1e-3", 1e-3), ("1E-2", 1e-2), ("+1e-3", 1e-3), (".5", 0.5), ("2.5e+1", 25.0),
     ("1.0e1", 10.0), ("5E0", 5.0), ("-0.0e0", 0.0), ("1.", 1.0), ("2", 2.0)],
)  # fmt: skip
def test_numbers_read_as_yaml_1_2_writes_them(tmp_path: Path, written: str, value: float) -> None:
    """PyYAML reads YAML 1.1, where '1e-3' is a string; a job file reads numbers as YAML 1.2."""
    step = written.lstrip("-") if 0 < value <= 0.5 else "null"  # 0 < step <= 0.5
    text = MINIMAL_JOB + f"repair:\n  budget: {written}\n  step: {step}\n"
    spec = load_job(write_fixture(tmp_path, text))
    assert spec.repair.budget == value and isinstance(spec.repair.budget, float)
    assert spec.repair.step == (value if step != "null" else None)


@pytest.mark.parametrize("written", ['"1e-3"', "'.5'", '"1E3"'])
def test_a_quoted_number_is_still_refused(tmp_path: Path, written: str) -> None:
    text = MINIMAL_JOB + f"repair:\n  budget: {written}\n"
    with pytest.raises(SpecError, match="repair.budget") as caught:
        load_job(write_fixture(tmp_path, text))
    assert caught.value.hint == "write the number without quotes"


@pytest.mark.parametrize("written", ["1e", "e3", "1e-", "1.2.3", "0x1p3", "1e3e3"])
def test_what_is_no_number_in_yaml_1_2_stays_a_string(tmp_path: Path, written: str) -> None:
    text = MINIMAL_JOB + f"repair:\n  budget: {written}\n"
    with pytest.raises(SpecError, match="must be a number"):
        load_job(write_fixture(tmp_path, text))


def test_an_exponent_integer_is_a_float_and_refused_where_an_integer_is_meant(
    tmp_path: Path,
) -> None:
    """YAML 1.2 reads 1e3 as a float: render.spp keeps its strict integer."""
    with pytest.raises(SpecError, match="render.spp: must be an integer, got 1000.0"):
        load_job(write_fixture(tmp_path, MINIMAL_JOB + "render:\n  spp: 1e3\n"))


def test_yaml_1_2_numbers_do_not_change_other_yaml_readers(tmp_path: Path) -> None:
    load_job(write_fixture(tmp_path, MINIMAL_JOB + "repair:\n  budget: 1e-3\n"))
    assert yaml.safe_load("a: 1e-3") == {"a": "1e-3"}  # PyYAML's own loader is left alone


def test_a_saved_job_copy_keeps_yaml_1_2_numbers_numbers(tmp_path: Path) -> None:
    """The copy 'sensaov view' writes re-reads the job file: 1e-3 must not come back quoted."""
    from sensaov_cli.job.load import job_copy_text

    job = load_job(write_fixture(tmp_path, MINIMAL_JOB + "repair:\n  budget: 1e-3\n"))
    copy = tmp_path / "copy.yaml"
    copy.write_text(job_copy_text(job, job.path, (), copy, job.output / "buffer.npz"))
    assert load_job(copy).repair.budget == 1e-3


def test_the_documented_example_is_valid(tmp_path: Path) -> None:
    docs = Path(__file__).resolve().parents[1] / "docs" / "job-spec.md"
    example = docs.read_text().split("```yaml\n")[1].split("```")[0]
    (tmp_path / "scenes" / "cbox").mkdir(parents=True)
    (tmp_path / "scenes" / "cbox" / "scene.xml").write_text("<scene/>\n")
    spec = load_job(write_fixture(tmp_path / "configs", example))
    assert spec.scene == tmp_path / "scenes" / "cbox" / "scene.xml"
    assert spec.output == tmp_path / "out" / "cbox"
    assert [o.type for o in spec.objectives] == [
        "mean_luminance",
        "region_luminance",
        "l2_to_target",
        "python",
    ]


def test_the_loader_does_not_import_the_renderer() -> None:
    code = "import sys, sensaov_cli.job.load\n"
    code += "print(sorted({'mitsuba', 'drjit'} & set(sys.modules)))"
    repo = Path(__file__).resolve().parents[1]
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=repo, capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == "[]"
