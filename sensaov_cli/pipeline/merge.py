"""Wire ``sensaov merge``: shard buffers (and their primals) -> one buffer and one primal.

The arithmetic and every refusal are in :mod:`sensaov_cli.buffer.shards`; this module reads the
files, finds each shard's primal beside it, and writes both results atomically together.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sensaov_cli import interrupts
from sensaov_cli.buffer.model import BUFFER_ID, SensitivityBuffer, new_buffer_id
from sensaov_cli.buffer.npz import buffer_writer, read_buffer
from sensaov_cli.buffer.shards import PRIMAL, Shard, merge_shards, pixels_digest, shard_task
from sensaov_cli.buffer.statistics import weighted_mean
from sensaov_cli.errors import MergeError, SensaovError
from sensaov_cli.outputs.atomic import (
    atomic_write_all,
    check_writable,
    made_by,
    provenance_attributes,
    recorded_inputs,
    refuse_unsafe_outputs,
)
from sensaov_cli.outputs.exr import exr_writer, read_exr
from sensaov_cli.pipeline.resolution import resolution, shards_hint
from sensaov_cli.progress import Progress

HINT_TOP = 5  # the top objects the hint speaks of, unless the job's render.until names its own


@dataclass(frozen=True)
class MergeOutputs:
    buffer: SensitivityBuffer  # written to the output, its primal to primal_beside(output)
    shards: int
    hint: tuple[str, ...] = ()  # what is still open, and about how many more shards resolve it


def primal_beside(buffer_path: Path) -> Path:
    """The primal written with a buffer: buffer.shard-1-of-4.npz -> primal.shard-1-of-4.exr."""
    name = buffer_path.name
    stem = name.removesuffix(".npz")
    if stem.startswith("buffer"):
        return buffer_path.with_name("primal" + stem.removeprefix("buffer") + ".exr")
    return buffer_path.with_name(stem + ".primal.exr")


def merge_files(paths: list[Path], output: Path, *, progress: Progress) -> MergeOutputs:
    primal_path = primal_beside(output)
    check_writable(output.parent, [output.name, primal_path.name])
    shards = []
    with progress.stage("read_s", f"reading {len(paths)} shard(s)"):
        for path in paths:
            buffer = read_buffer(path)
            shards.append(Shard(path, buffer, shard_task(path, buffer.provenance)))
    read = [*paths, *map(primal_beside, paths)]
    read += [path for shard in shards for path in recorded_inputs(shard.buffer.provenance)]
    refuse_unsafe_outputs(
        read, [output, primal_path], where=str(output), hint="name another file with -o"
    )
    with progress.stage("merge_s", "merging"):
        merged = merge_shards(shards)
        # A merge is a new buffer: outputs made from a shard (or an earlier merge) are not its.
        merged.provenance.update(made_by("merge"), **{BUFFER_ID: new_buffer_id()})
        primal = _merged_primal(shards)
        merged.provenance[PRIMAL] = {"file": primal_path.name, "sha256": pixels_digest(primal)}
    interrupts.raise_if_stopped()
    with progress.stage("write_s", f"writing {output.name} and {primal_path.name}"):
        attributes = provenance_attributes(merged.provenance, relative_to=output.parent)
        try:
            atomic_write_all(
                [(output, buffer_writer(merged)), (primal_path, exr_writer(primal, attributes))]
            )
        except OSError as exc:
            raise SensaovError(
                f"cannot write outputs: {exc.strerror or exc}", where=str(output.parent)
            ) from exc
    return MergeOutputs(merged, len(shards), tuple(shards_hint(resolution(merged, _top(merged)))))


def _top(buffer: SensitivityBuffer) -> int:
    """The job's render.until top count when it set one, else HINT_TOP."""
    until = ((buffer.provenance.get("job") or {}).get("render") or {}).get("until")
    top = until.get("resolved") if isinstance(until, dict) else None
    return top if isinstance(top, int) and top >= 1 else HINT_TOP


def _merged_primal(shards: list[Shard]) -> dict[str, np.ndarray]:
    """The spp-weighted mean of one primal per shard index (objective splits share it)."""
    first = {shard.task.index: shard for shard in reversed(shards)}  # the first of each index
    ordered = [first[index] for index in sorted(first)]
    images = []
    width, height = shards[0].buffer.provenance["resolution"]  # checked: two positive ints
    for shard in ordered:
        path = primal_beside(shard.path)
        if not path.exists():
            raise MergeError("the shard's primal is missing", where=str(path))
        channels, _ = read_exr(path, "shard's primal")
        if not channels or any(c.shape != (height, width) for c in channels.values()):
            raise MergeError(f"the primal is not the shard's {width}x{height}", where=str(path))
        if pixels_digest(channels) != shard.task.primal_digest:
            raise MergeError(
                f"not the primal {shard.path.name} was written with (its pixels differ from "
                "the ones the shard records): another job's or another shard's file",
                where=str(path),
                hint="run that shard again ('sensaov run JOB --shard I/N')",
            )
        images.append(channels)
    for image, shard in zip(images, ordered, strict=True):
        if list(image) != list(images[0]):
            where = str(primal_beside(shard.path))
            raise MergeError("this primal has other channels than the first shard's", where=where)
    spp = [int(shard.buffer.provenance["spp"]) for shard in ordered]
    return {name: weighted_mean([image[name] for image in images], spp) for name in images[0]}
