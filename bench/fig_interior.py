"""Figure 14: a real interior's buffer, its size and `sensaov rank` on it (numpy only).

Bitterli's kitchen (295 meshes, 11 image files) made a 410 MB buffer at 140x80 in format 3:
splitting its shared BSDFs turned the 11 images into 40 texture copies, each stored with its
value and gradient, 16 with no gradient at all; `rank` took 1.7-3 s on it. A buffer of 8,000
parameters took 7-15 s to read, and a zip of 100,000 members kept `rank` busy for minutes.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench import notes
from bench.fig_process import SENSAOV
from bench.jobs import Workspace
from bench.results import Figure, Goal, Row, fmt
from bench.settings import Settings
from bench.timing import Stats, interleave, run_child
from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.npz import buffer_writer, read_buffer
from sensaov_cli.outputs.atomic import atomic_write

MB = 1e6
Log = Callable[[str], None]
# The kitchen as the issue measured it: copies of each of its 11 images after splitting (40 in
# all), 16 of them never seen (no gradient), 295 meshes with a colour and a roughness each.
COPIES = (8, 6, 5, 4, 4, 3, 3, 2, 2, 2, 1)
UNSEEN = 16
MESHES = 295
SEEN_TEXELS = 0.35  # share of a seen texture's texels with a gradient at 140x80
KITCHEN_SIDE = 640  # 40 copies of value and gradient at 640²x3: format 3 stores ~400 MB


def kitchen(side: int) -> SensitivityBuffer:
    """A buffer shaped like the kitchen's: ``side``² RGB images, split per owner."""
    rng = np.random.default_rng(0)
    params, values, grads = [], {}, {}
    copy = 0
    for owners in COPIES:
        pixels = rng.random((side, side, 3), dtype=np.float32)
        for _ in range(owners):
            key = f"Mesh{copy:03d}.bsdf.brdf_0.reflectance.data"
            params.append(ParamRecord(key, "reflectance", (f"Mesh{copy:03d}",), pixels.shape,
                                      True, "diffuse", (), "verified", ""))  # fmt: skip
            values[key] = pixels
            seen = copy >= UNSEEN
            mask = rng.random(pixels.shape[:2]) < SEEN_TEXELS if seen else np.zeros((side, side))
            grads[key] = (rng.standard_normal(pixels.shape) * 1e-6 * mask[..., None]).astype(
                np.float32
            )
            copy += 1
    for mesh in range(MESHES):
        for slot, shape in (("reflectance.value", (3,)), ("alpha.value", (1,))):
            key = f"Mesh{mesh:03d}_x.bsdf.{slot}"
            kind = "reflectance" if slot.startswith("refl") else "roughness"
            params.append(ParamRecord(key, kind, (f"Mesh{mesh:03d}",), shape, False,
                                      "roughplastic", (), "verified", ""))  # fmt: skip
            values[key] = rng.random(shape, dtype=np.float32)
            grads[key] = rng.standard_normal(shape).astype(np.float32) * 1e-3
    return _buffer(params, values, grads, tuple(f"Mesh{i:03d}" for i in range(MESHES)))


def many_parameters(count: int) -> SensitivityBuffer:
    rng = np.random.default_rng(1)
    params = [ParamRecord(f"o{i}.bsdf.reflectance.value", "reflectance", (f"o{i}",), (3,),
                          False, "diffuse", (), "verified", "") for i in range(count)]  # fmt: skip
    values = {p.key: rng.random(3, dtype=np.float32) for p in params}
    grads = {p.key: rng.standard_normal(3).astype(np.float32) for p in params}
    return _buffer(params, values, grads, tuple(f"o{i}" for i in range(count)))


def _buffer(
    params: list[ParamRecord], values: dict, grads: dict, objects: tuple[str, ...]
) -> SensitivityBuffer:
    return SensitivityBuffer(
        provenance={"tool": "bench"},
        objects=objects,
        params=tuple(params),
        objectives=(ObjectiveRecord("mean_luma", {"type": "mean_luminance"}, 0.3, 1),),
        values=values,
        grads={"mean_luma": grads},
    )


def version_3_size(buffer: SensitivityBuffer) -> float:
    """Bytes of the same buffer in format 3: one .npy member (128-byte header) per array."""
    arrays = [buffer.value(p.key) for p in buffer.params]
    arrays += [buffer.grad("mean_luma", p.key) for p in buffer.params]
    return sum(128 + a.nbytes for a in arrays) / MB


def interior(ws: Workspace, s: Settings, log: Log) -> Figure:
    side = 64 if s.quick else KITCHEN_SIDE
    figure = Figure(
        14,
        "A real interior's buffer: size, and `sensaov rank` on it",
        "`sensaov rank` on the kitchen-sized buffer ≤ 0.5 s, on 8,000 parameters ≤ 1 s; a "
        "100,000-member zip refused ≤ 1 s",
        f"A buffer built in numpy shaped like Bitterli's kitchen at 140×80: 11 images of "
        f"{side}²×3 split into {sum(COPIES)} texture copies (one per owner), {UNSEEN} of them "
        f"with no gradient, the others with {SEEN_TEXELS:.0%} of their texels seen; {MESHES} "
        "meshes with a colour and a roughness each; one objective. Its format 3 size is the sum "
        "of the members format 3 would store. Whole-process wall time of the installed "
        "`sensaov` script (spawn to exit, start-up included), interleaved with `--by object` "
        "and with a buffer of 8,000 colours; the 100,000-member zip is the kitchen's buffer "
        "with 100,000 extra members. `read_buffer` in-process: every member read and checked "
        "(as `project` and `report` read), and lazily (as `rank` reads: header, packed members "
        "and parameter sums, no texel).",
    )
    figure.why_missed = notes.INTERIOR
    buffer = kitchen(side)
    path = ws.root / "interior" / "buffer.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, buffer_writer(buffer))
    many = ws.root / "interior" / "many.npz"
    atomic_write(many, buffer_writer(many_parameters(8000)))
    forged = _forged(path, ws.root / "interior" / "forged.npz")
    commands = {
        "rank": [SENSAOV, "rank", str(path)],
        "by_object": [SENSAOV, "rank", str(path), "--by", "object"],
        "many": [SENSAOV, "rank", str(many), "--by", "object"],
    }
    timings: dict[str, Callable[[], float]] = {k: _wall(c) for k, c in commands.items()}
    timings["forged"] = _refused([SENSAOV, "rank", str(forged)])
    timings["read"] = _read(path)
    timings["read_lazy"] = _read(path, lazy=True)
    t = interleave(timings, s.startup_rounds)
    size = path.stat().st_size / MB
    figure.rows += [
        Row(
            "file size, format 4",
            Stats.of([size]),
            "MB",
            None,
            f"format 3 would store {fmt(version_3_size(buffer), 'MB')}",
        ),  # fmt: skip
        Row("sensaov rank (kitchen)", t["rank"], "s", Goal("<=", 0.5)),
        Row("sensaov rank --by object (kitchen)", t["by_object"], "s", Goal("<=", 0.5)),
        Row("read_buffer (kitchen), in-process", t["read"], "s"),
        Row("read_buffer (kitchen), lazy as rank reads it, in-process", t["read_lazy"], "s"),
        Row("sensaov rank --by object (8,000 parameters)", t["many"], "s", Goal("<=", 1.0)),
        Row("sensaov rank, 100,000-member zip (refused)", t["forged"], "s", Goal("<=", 1.0)),
    ]
    log("figure 14: done")
    return figure


def _forged(good: Path, forged: Path) -> Path:
    import io
    import shutil
    import zipfile

    shutil.copyfile(good, forged)
    member = io.BytesIO()
    np.lib.format.write_array(member, np.zeros(3, np.float32))
    with zipfile.ZipFile(forged, "a") as zf:
        for i in range(100_000):
            zf.writestr(f"extra_{i:06d}.npy", member.getvalue())
    return forged


def _wall(command: list[str]) -> Callable[[], float]:
    return lambda: run_child(command).seconds


def _refused(command: list[str]) -> Callable[[], float]:
    """Wall time of a command that must refuse its input (exit 2) in one line."""

    def measure() -> float:
        start = time.perf_counter()
        result = subprocess.run(command, capture_output=True, text=True)
        seconds = time.perf_counter() - start
        if result.returncode != 2 or len(result.stderr.splitlines()) != 1:
            raise RuntimeError(f"expected one line and exit 2, got {result.stderr[-500:]}")
        return seconds

    return measure


def _read(path: Path, lazy: bool = False) -> Callable[[], float]:
    def measure() -> float:
        start = time.perf_counter()
        read_buffer(path, lazy=lazy)
        return time.perf_counter() - start

    return measure
