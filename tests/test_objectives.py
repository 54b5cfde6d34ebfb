"""Objective values and image-space adjoints against numpy, on synthetic images (no rendering)."""

from __future__ import annotations

import textwrap
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from sensaov_cli.errors import ObjectiveError, SpecError
from sensaov_cli.job.spec import ObjectiveSpec
from sensaov_cli.render.objectives import REC709_LUMA, build_objectives, value_and_adjoint

H, W = 6, 8


def spec(name: str, kind: str, **fields: object) -> ObjectiveSpec:
    values = {"region": None, "mask": None, "target": None, "function": None, "path": None}
    values.update(fields)
    return ObjectiveSpec(name=name, type=kind, **values)  # type: ignore[arg-type]


@pytest.fixture
def image(mi: ModuleType) -> tuple[np.ndarray, object]:
    pixels = np.random.default_rng(1).random((H, W, 3)).astype(np.float32)
    return pixels, mi.TensorXf(pixels)


def evaluate(
    mi: ModuleType, objective_spec: ObjectiveSpec, tensor: object, allow_python: bool = False
):
    (objective,) = build_objectives(mi, (objective_spec,), (H, W), allow_python)
    value, adjoint = value_and_adjoint(mi, objective, tensor)
    return value, np.asarray(adjoint)


def test_mean_luminance_value_and_adjoint(mi, image) -> None:  # noqa: ANN001
    pixels, tensor = image
    value, adjoint = evaluate(mi, spec("m", "mean_luminance"), tensor)
    luma = pixels @ np.array(REC709_LUMA, np.float32)
    assert value == pytest.approx(luma.mean(), rel=1e-5)
    expected = np.broadcast_to(np.array(REC709_LUMA, np.float32) / (H * W), (H, W, 3))
    np.testing.assert_allclose(adjoint, expected, rtol=1e-6)


def test_region_luminance_sees_only_pixel_centres_inside(mi, image) -> None:  # noqa: ANN001
    pixels, tensor = image
    value, adjoint = evaluate(
        mi, spec("r", "region_luminance", region=(0.0, 0.5, 0.5, 1.0)), tensor
    )
    inside = pixels[H // 2 :, : W // 2] @ np.array(REC709_LUMA, np.float32)
    assert value == pytest.approx(inside.mean(), rel=1e-5)
    assert np.all(adjoint[: H // 2] == 0) and np.all(adjoint[:, W // 2 :] == 0)
    assert adjoint.sum() == pytest.approx(sum(REC709_LUMA), rel=1e-5)


def test_l2_to_target_value_and_adjoint(mi, image, tmp_path: Path) -> None:  # noqa: ANN001
    import OpenEXR

    pixels, tensor = image
    target = np.full((H, W, 3), 0.25, np.float32)
    path = tmp_path / "target.exr"
    channels = {c: np.ascontiguousarray(target[..., i]) for i, c in enumerate("RGB")}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, channels) as exr:
        exr.write(str(path))
    value, adjoint = evaluate(mi, spec("l", "l2_to_target", target=path), tensor)
    assert value == pytest.approx(np.mean((pixels - target) ** 2), rel=1e-5)
    np.testing.assert_allclose(adjoint, 2 * (pixels - target) / pixels.size, rtol=1e-5, atol=1e-9)


def test_target_of_the_wrong_size_is_refused(mi, tmp_path: Path) -> None:  # noqa: ANN001
    import OpenEXR

    path = tmp_path / "small.exr"
    with OpenEXR.File({}, {"R": np.zeros((2, 2), np.float32)}) as exr:
        exr.write(str(path))
    with pytest.raises(SpecError, match="2x2") as info:
        build_objectives(mi, (spec("l", "l2_to_target", target=path),), (H, W), False)
    assert "objectives[0].target" in str(info.value)


def write_module(tmp_path: Path, body: str) -> tuple[Path, str]:
    """A user module with a name unique to the test (Python caches imported modules by name)."""
    name = f"userobj_{abs(hash(str(tmp_path)))}"
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(body))
    return tmp_path, name


def test_python_objective_needs_opt_in(mi, tmp_path: Path) -> None:  # noqa: ANN001
    folder, name = write_module(tmp_path, "def f(image):\n    return image[0, 0, 0]\n")
    user = spec("u", "python", function=f"{name}:f", path=folder)
    with pytest.raises(SpecError, match="--allow-python"):
        build_objectives(mi, (user,), (H, W), False)


def test_python_objective_is_differentiated_like_a_builtin(mi, image, tmp_path: Path) -> None:  # noqa: ANN001
    pixels, tensor = image
    folder, name = write_module(
        tmp_path,
        """
        import drjit as dr

        def red_energy(image):
            return dr.sum(dr.square(image[:, :, 0]), axis=None)
        """,
    )
    user = spec("u", "python", function=f"{name}:red_energy", path=folder)
    value, adjoint = evaluate(mi, user, tensor, allow_python=True)
    assert value == pytest.approx(float((pixels[..., 0] ** 2).sum()), rel=1e-5)
    np.testing.assert_allclose(adjoint[..., 0], 2 * pixels[..., 0], rtol=1e-5)
    assert np.all(adjoint[..., 1:] == 0)


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("def f(image):\n    return image * 2\n", "scalar"),
        ("def f(image):\n    raise ValueError('bad')\n", "ValueError: bad"),
        ("import sys\ndef f(image):\n    sys.exit(0)\n", "SystemExit"),
        (
            "import drjit as dr\n"
            "def f(image):\n    return dr.sum(image, axis=None) * float('nan')\n",
            "NaN",
        ),
    ],
)
def test_bad_user_objectives_fail_with_one_line(
    mi, image, tmp_path: Path, body: str, message: str
) -> None:  # noqa: ANN001
    _, tensor = image
    folder, name = write_module(tmp_path, body)
    user = spec("u", "python", function=f"{name}:f", path=folder)
    with pytest.raises(ObjectiveError, match=message) as info:
        evaluate(mi, user, tensor, allow_python=True)
    assert "objectives[0]" in str(info.value)


def test_region_from_a_mask_image_weights_pixels_by_the_mask(mi, image, tmp_path: Path) -> None:  # noqa: ANN001
    import OpenEXR

    pixels, tensor = image
    mask = np.zeros((H, W), np.float32)
    mask[1:3, 2:6] = 1.0
    mask[4, 0] = 0.5  # soft masks weight their pixels
    path = tmp_path / "mask.exr"
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"Y": mask}) as exr:
        exr.write(str(path))
    value, adjoint = evaluate(mi, spec("m", "region_luminance", mask=path), tensor)
    luma = pixels @ np.array(REC709_LUMA, np.float32)
    assert value == pytest.approx(float((luma * mask).sum() / mask.sum()), rel=1e-5)
    assert np.all(adjoint[mask == 0] == 0)
