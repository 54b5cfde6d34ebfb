"""Scalar objectives M(I) of the objective camera's image (paper §5).

Each is a Dr.Jit function of the image tensor; value and adjoint dM/dI come from
differentiating it on a detached leaf image, so built-in and user objectives share one door.
"""

from __future__ import annotations

import importlib
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from sensaov_cli.errors import ObjectiveError, SpecError
from sensaov_cli.job.spec import ObjectiveSpec
from sensaov_cli.limits import check_memory, regular_file

# Rec. 709 / sRGB primaries, the photometric response of the paper's example objective.
REC709_LUMA = (0.2126, 0.7152, 0.0722)


@dataclass(frozen=True)
class Objective:
    spec: ObjectiveSpec
    index: int
    function: Callable[[Any], Any]  # Dr.Jit image tensor (H, W, C) -> scalar

    @property
    def where(self) -> str:
        return f"objectives[{self.index}]"


def build_objectives(
    mi: ModuleType, specs: tuple[ObjectiveSpec, ...], size: tuple[int, int], allow_python: bool
) -> list[Objective]:
    """The job's objectives as functions of an image of ``size`` = (height, width); files and
    user functions are checked here, before anything is rendered."""
    return [
        Objective(spec, index, _function(mi, spec, index, size, allow_python))
        for index, spec in enumerate(specs)
    ]


def value_and_adjoint(mi: ModuleType, objective: Objective, image: Any) -> tuple[float, Any]:
    """M at ``image`` and dM/dI, both checked to be finite."""
    import drjit as dr

    leaf = mi.TensorXf(dr.detach(image))
    dr.enable_grad(leaf)
    try:
        value = objective.function(leaf)
    except (Exception, SystemExit) as exc:  # user code: one line, where it came from
        raise ObjectiveError(
            f"objective function raised {type(exc).__name__}: {exc}", where=objective.where
        ) from exc
    if not (dr.is_array_v(value) and dr.width(value) == 1 and dr.is_diff_v(value)):
        raise ObjectiveError(
            "objective must return a differentiable scalar (a Dr.Jit value of size 1)",
            where=objective.where,
            hint="build it from the image tensor with Dr.Jit operations",
        )
    dr.backward(value)
    adjoint = dr.grad(leaf)
    scalar = float(np.asarray(dr.detach(value)).reshape(-1)[0])
    if not math.isfinite(scalar) or not np.all(np.isfinite(np.asarray(adjoint))):
        raise ObjectiveError(
            "objective value or its image gradient is NaN or infinite", where=objective.where
        )
    return scalar, adjoint


def _function(
    mi: ModuleType, spec: ObjectiveSpec, index: int, size: tuple[int, int], allow_python: bool
) -> Callable[[Any], Any]:
    where = f"objectives[{index}]"
    if spec.type == "mean_luminance":
        return _mean_luminance(mi, np.ones(size, np.float32))
    if spec.type == "region_luminance":
        return _mean_luminance(mi, _region_mask(spec, size, where))
    if spec.type == "l2_to_target":
        return _l2_to_target(mi, _read_image(spec.target, size, f"{where}.target"))
    return _user_function(spec, where, allow_python)  # "python": the spec admits no other


def colour_channels(channels: int) -> int:
    """Colour channels of an image with ``channels`` in all: Y[A] renders have 1, RGB[A] 3."""
    return 1 if channels <= 2 else 3


def _channel_weights(mask: np.ndarray, channels: int, per_channel: tuple[float, ...]) -> np.ndarray:
    """(H, W, C) weights: ``mask`` times a weight per colour channel; alpha gets none."""
    weights = np.zeros((*mask.shape, channels), np.float32)
    for channel, weight in enumerate(per_channel[:channels]):
        weights[..., channel] = mask * weight
    return weights


def _mean_luminance(mi: ModuleType, mask: np.ndarray) -> Callable[[Any], Any]:
    """M = sum(w * I): the mask-weighted mean of Rec. 709 luminance; linear in the image."""
    import drjit as dr

    def objective(image: Any) -> Any:
        channels = image.shape[2]
        luma = REC709_LUMA if colour_channels(channels) == 3 else (1.0,)  # mono: Y already
        weights = _channel_weights(mask / np.float32(mask.sum()), channels, luma)
        return dr.sum(image * mi.TensorXf(weights), axis=None)

    return objective


def _region_mask(spec: ObjectiveSpec, size: tuple[int, int], where: str) -> np.ndarray:
    height, width = size
    if spec.region is not None:
        x0, y0, x1, y1 = spec.region
        xs = (np.arange(width) + 0.5) / width  # pixel centres in normalised coordinates
        ys = (np.arange(height) + 0.5) / height
        mask = np.outer((ys >= y0) & (ys < y1), (xs >= x0) & (xs < x1)).astype(np.float32)
    else:
        pixels = _read_image(spec.mask, size, f"{where}.mask")
        if (pixels[..., 0] < 0).any():  # M would weigh some pixels negatively: not a mean
            raise SpecError(
                f"{spec.mask} holds negative weights (least {pixels[..., 0].min():g})",
                where=f"{where}.mask",
                hint="a mask weighs pixels by 0 (ignored) to 1 (counted); write values >= 0",
            )
        mask = np.ascontiguousarray(pixels[..., 0])  # first channel; grey masks have one
    if not mask.sum() > 0:  # also catches NaN in a mask image
        key = "region" if spec.region is not None else "mask"
        raise SpecError(
            f"the {key} selects no pixel at this resolution (or the mask holds NaN)",
            where=f"{where}.{key}",
            hint="enlarge the region, raise the resolution, or check the mask image",
        )
    return mask


def _read_image(path: Path | None, size: tuple[int, int], where: str) -> np.ndarray:
    """The image at ``path`` as (H, W, C) float32, checked finite and of ``size``."""
    import OpenImageIO as oiio

    regular_file(Path(str(path)), "image", where=where, error=SpecError)  # a FIFO blocks OIIO
    image = oiio.ImageInput.open(str(path))
    if image is None:
        raise SpecError(f"cannot read image {path}: {oiio.geterror()}", where=where)
    try:
        spec = image.spec()  # the declared size, checked before a pixel is allocated
        check_memory(spec.width * spec.height * spec.nchannels * 4 * 2,
                     f"reading {path}, which declares {spec.width}x{spec.height} pixels,",
                     where=where, hint="check the image")  # fmt: skip
        pixels = image.read_image(format="float")
    finally:
        image.close()
    if pixels is None:
        raise SpecError(f"cannot decode image {path}", where=where)
    pixels = np.asarray(pixels, dtype=np.float32).reshape(pixels.shape[0], pixels.shape[1], -1)
    if not np.isfinite(pixels).all():
        raise SpecError(
            f"{path} holds NaN or infinite pixels", where=where, hint="write finite values"
        )
    if pixels.shape[:2] != size:
        raise SpecError(
            f"{path} is {pixels.shape[1]}x{pixels.shape[0]} "
            f"but the objective image is {size[1]}x{size[0]}",
            where=where,
            hint="render.resolution must match the image's size",
        )
    return pixels


def _l2_to_target(mi: ModuleType, pixels: np.ndarray) -> Callable[[Any], Any]:
    """M = mean over pixels and colour channels of (I - T)^2; alpha takes no part."""
    import drjit as dr

    if pixels.shape[2] < 3:  # a grey target compares against every colour channel
        pixels = np.repeat(pixels[..., :1], 3, axis=2)
    target = np.ascontiguousarray(pixels[..., :3])

    def objective(image: Any) -> Any:
        channels = image.shape[2]
        colours = colour_channels(channels)
        reference = np.zeros((*target.shape[:2], channels), np.float32)
        if colours == 3:
            reference[..., :3] = target
        else:  # a mono render is compared with the target's luminance
            reference[..., 0] = target @ np.array(REC709_LUMA, np.float32)
        weights = _channel_weights(
            np.ones(target.shape[:2], np.float32), channels, (1.0,) * colours
        )
        weights /= np.float32(weights.sum())
        return dr.sum(dr.square(image - mi.TensorXf(reference)) * mi.TensorXf(weights), axis=None)

    return objective


def _user_function(spec: ObjectiveSpec, where: str, allow_python: bool) -> Callable[[Any], Any]:
    if not allow_python:
        raise SpecError(
            "python objectives run code from the job and need an explicit opt-in",
            where=where,
            hint="pass --allow-python",
        )
    assert spec.function is not None
    module_name, attribute = spec.function.split(":")
    search = str(spec.path) if spec.path else None
    if search and search not in sys.path:
        sys.path.insert(0, search)
    try:
        module = importlib.import_module(module_name)
        function = getattr(module, attribute)
    except (Exception, SystemExit) as exc:
        raise SpecError(
            f"cannot load {spec.function}: {type(exc).__name__}: {exc}", where=f"{where}.function"
        ) from exc
    if not callable(function):
        raise SpecError(f"{spec.function} is not callable", where=f"{where}.function")
    return function
