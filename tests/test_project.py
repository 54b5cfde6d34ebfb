"""`sensaov project`: visibility, Cryptomatte, painted channels and the EXR contract."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.buffer.queries import per_object
from sensaov_cli.outputs.exr import read_exr

from .conftest import SCENES, sensaov, write_job
from .test_cryptomatte import decode_file

CAMERAS = [
    {"name": "objective", "objective": True, "vis_spp": 16},
    {
        "name": "high",
        "look_at": {"origin": [0.3, 0.6, 3.2], "target": [0, -0.2, 0], "up": [0, 1, 0]},
        "fov": 45,
        "resolution": [40, 32],
        "vis_spp": 16,
    },
]
CHANNELS = [
    {"name": "objects", "kind": "object"},
    {"name": "types", "kind": "type"},
    {"name": "shared", "kind": "object", "normalize": "shared", "tonemap": "symlog"},
]
NAME_RULE = re.compile(r"^[A-Za-z0-9_]{1,63}(\.[A-Za-z0-9_]{1,63})*$")


@pytest.fixture(scope="module")
def projected(job_writer: Callable[..., Path]) -> Path:
    job = job_writer("project", inspection_cameras=CAMERAS, channels=CHANNELS)
    assert sensaov("run", "-q", str(job)).returncode == 0
    done = sensaov("project", str(job), "--png")
    assert done.returncode == 0, done.stderr
    assert "high: 40x32, 16 vis spp" in done.stdout  # time per camera reported
    return job.parent / "out"


def exr(out: Path, camera: str) -> tuple[dict[str, np.ndarray], dict]:
    return read_exr(out / f"{camera}.exr")


def test_one_exr_per_camera_and_previews(projected: Path) -> None:
    assert (projected / "objective.exr").is_file() and (projected / "high.exr").is_file()
    assert (projected / "previews" / "high_mean_luma.png").is_file()
    assert not list(projected.rglob("*.partial"))


@pytest.mark.parametrize("camera", ["objective", "high"])
def test_cryptomatte_decodes_to_manifest_names_and_coverage_sums_to_one(
    projected: Path, camera: str
) -> None:
    names, coverages, manifest = decode_file(projected / f"{camera}.exr", "CryptoObject")
    buffer = read_buffer(projected / "buffer.npz")
    assert set(manifest) == set(buffer.objects)
    total = np.sum(coverages, axis=0)
    channels, _ = exr(projected, camera)
    alpha = channels["A"]
    hit = alpha > 0
    assert hit.any()
    np.testing.assert_allclose(total[hit], alpha[hit], atol=1e-6)  # ranks + background = 1
    full = alpha == 1
    np.testing.assert_allclose(total[full], 1.0, atol=1e-6)
    seen = {n for rank in names for n in rank.ravel() if n is not None}
    assert seen <= set(buffer.objects) and "back_wall" in seen


def test_object_channel_equals_buffer_aggregate_from_two_cameras(projected: Path) -> None:
    buffer = read_buffer(projected / "buffer.npz")
    # The headline layer adds up the gradients sensaov stands behind (docs/encoding.md)
    trusted = [p.key for p in buffer.params if p.trust in ("verified", "no_gradient")]
    # painted with the default score, the signed sum (docs/rankings.md, "One score")
    expected = per_object(buffer, "mean_luma", method="sum", weight="value", keys=trusted)
    checked = 0
    for camera in ("objective", "high"):
        channels, _ = exr(projected, camera)
        names, coverages, _ = decode_file(projected / f"{camera}.exr", "CryptoObject")
        painted = channels["mean_luma.objects.Y"]
        for name in buffer.objects:
            full = (names[0] == name) & (coverages[0] == 1.0)
            if full.sum() < 4:
                continue
            mean = float(np.abs(painted[full]).mean())
            assert mean == pytest.approx(expected[name], rel=1e-6), (camera, name)
            checked += 1
    assert checked >= 8


def test_channel_names_follow_the_rules_and_carry_metadata(projected: Path) -> None:
    channels, header = exr(projected, "high")
    for name in channels:
        assert NAME_RULE.match(name), name
        assert all(len(token.encode()) <= 63 for token in name.split("."))
    sensitivity = [n for n in channels if n.endswith(".Y")]
    assert {"mean_luma.objects.Y", "mean_luma.types_reflectance.Y", "mean_luma.shared.Y"} <= set(
        sensitivity
    )
    for name in sensitivity:
        layer = name[: -len(".Y")]
        keys = [
            k
            for k, v in header.items()
            if k.startswith("sensaov/") and k.endswith("/name") and v == layer
        ]
        assert len(keys) == 1, layer
        prefix = keys[0][: -len("/name")]
        for field in (
            "objective",
            "selection",
            "aggregate",
            "weight",
            "encoding",
            "scale",
            "estimators",
        ):
            assert f"{prefix}/{field}" in header, (layer, field)
        for field in ("spp", "buffer", "camera"):  # the file's provenance, once (format 3)
            assert f"{prefix}/{field}" not in header, (layer, field)
        estimators = json.loads(header[f"{prefix}/estimators"])
        assert sorted(estimators) == sorted(json.loads(header[f"{prefix}/keys"]))
        if layer == "mean_luma.objects":  # roughplastic's alpha and eta are repaired
            assert estimators["blue_plastic.alpha"] == "finite-difference"
    assert "CryptoObject.R" not in channels  # no deprecated preview layer
    provenance = json.loads(header["sensaov/provenance"])
    assert provenance["command"] == "project" and provenance["buffer"] == "buffer.npz"


def scale_of(header: dict, layer: str) -> str:
    (key,) = [
        k
        for k, v in header.items()
        if k.endswith("/name") and v == layer and k.startswith("sensaov/")
    ]
    return header[key.replace("/name", "/scale")]


def test_shared_normalisation_gives_one_scale_in_every_file(projected: Path) -> None:
    scales = {
        camera: scale_of(exr(projected, camera)[1], "mean_luma.shared")
        for camera in ("objective", "high")
    }
    assert scales["objective"] == scales["high"]
    data = exr(projected, "high")[0]["mean_luma.shared.Y"]
    assert np.abs(data).max() <= 1.0 + 1e-6


def test_default_channels_are_linear_and_unnormalised(projected: Path) -> None:
    _, header = exr(projected, "objective")
    encoding = [v for k, v in header.items() if k.endswith("/encoding") and "normalize=none" in v]
    assert encoding and all("tonemap=none" in e for e in encoding)


def test_project_computes_no_derivatives(
    job_writer: Callable[..., Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    import drjit as dr

    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.project import project_job
    from sensaov_cli.progress import Progress

    job = job_writer("no_ad", inspection_cameras=CAMERAS[1:])
    assert sensaov("run", "-q", str(job)).returncode == 0

    def forbidden(*args: object, **kwargs: object) -> None:
        raise AssertionError("project tried to differentiate")

    for name in (
        "enable_grad",
        "backward",
        "backward_from",
        "backward_to",
        "forward",
        "forward_from",
        "forward_to",
    ):
        monkeypatch.setattr(dr, name, forbidden)
    spec = load_job(job)
    views = project_job(spec, buffer_path=spec.output / "buffer.npz", progress=Progress(quiet=True))
    assert [view.camera for view in views] == ["objective", "high"]


def test_changed_scene_is_refused_unless_forced(tmp_path: Path) -> None:
    scene_dir = tmp_path / "scene"
    shutil.copytree(SCENES / "cbox", scene_dir)
    scene = scene_dir / "scene.xml"
    job = write_job(tmp_path, inspection_cameras=CAMERAS[:1])
    job.write_text(job.read_text().replace(str(SCENES / "cbox" / "scene.xml"), str(scene)))
    assert sensaov("run", "-q", str(job)).returncode == 0
    scene.write_text(scene.read_text() + "<!-- edited -->\n")
    refused = sensaov("project", str(job), "-q")
    assert (
        refused.returncode == 2 and "fingerprint" in refused.stderr and "--force" in refused.stderr
    )
    assert not (tmp_path / "out" / "objective.exr").exists()
    assert sensaov("project", str(job), "-q", "--force").returncode == 0


def test_unknown_camera_and_corrupt_buffer_are_one_line_errors(
    projected: Path, tmp_path: Path
) -> None:
    job = projected.parent / "job.yaml"
    unknown = sensaov("project", str(job), "--camera", "nope")
    assert (
        unknown.returncode == 2
        and "high" in unknown.stderr
        and len(unknown.stderr.splitlines()) == 1
    )
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"PK\x03\x04 not really a zip")
    corrupt = sensaov("project", str(job), "--buffer", str(broken))
    assert (
        corrupt.returncode == 2
        and "broken.npz" in corrupt.stderr
        and "Traceback" not in corrupt.stderr
    )


def test_material_cryptomatte_merges_objects_sharing_a_bsdf(projected: Path) -> None:
    names, coverages, manifest = decode_file(projected / "objective.exr", "CryptoMaterial")
    assert {"white", "checker", "green", "glass"} <= set(manifest)
    assert "floor" not in manifest  # objects are in CryptoObject, not here
    object_names, object_coverages, _ = decode_file(projected / "objective.exr", "CryptoObject")
    on_floor = (object_names[0] == "floor") & (object_coverages[0] == 1.0)
    assert on_floor.any() and set(names[0][on_floor].ravel()) == {"white"}
    total = np.sum(coverages, axis=0)
    assert np.all(total <= 1.0 + 1e-6)


def test_camera_names_of_run_outputs_are_reserved(job_writer: Callable[..., Path]) -> None:
    cameras = [{"name": "primal", "look_at": CAMERAS[1]["look_at"]}]
    done = sensaov("validate", str(job_writer("reserved", inspection_cameras=cameras)))
    assert (
        done.returncode == 2
        and "reserved" in done.stderr
        and "inspection_cameras[0].name" in done.stderr
    )


def test_a_camera_named_twice_is_rendered_once(projected: Path) -> None:
    done = sensaov(
        "project", str(projected.parent / "job.yaml"), "--camera", "high", "--camera", "high"
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("high:") == 1


def test_a_select_channel_matching_nothing_is_bad_input(projected: Path, tmp_path: Path) -> None:
    job = write_job(tmp_path, channels=[{"name": "none", "kind": "select", "select": "nomatch*"}])
    job.write_text(job.read_text().replace(str(tmp_path / "out"), str(projected)))
    done = sensaov("project", str(job), "-q")
    assert done.returncode == 2 and "channels[0].select" in done.stderr
