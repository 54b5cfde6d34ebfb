"""Wire ``sensaov project``'s forward and transport layers: the objective camera's, from the
forward sidecar ``sensaov run`` wrote beside its buffer (§4, §7)."""

from __future__ import annotations

import json
import re
from pathlib import Path

from sensaov_cli.buffer.forward_sidecar import check_belongs, read_forward
from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.statistics import single_pass
from sensaov_cli.errors import SpecError
from sensaov_cli.job.spec import JobSpec
from sensaov_cli.outputs.layered_exr import SensitivityLayer
from sensaov_cli.pipeline.run import FORWARD_NAME
from sensaov_cli.progress import Progress
from sensaov_cli.views.transport import forward_views, transport_views


def projected_layers(
    job: JobSpec, buffer: SensitivityBuffer, buffer_path: Path, progress: Progress
) -> list[SensitivityLayer]:
    """The objective camera's forward and transport layers, each in its display scale group:
    a forward channel alone, a transport entry's layers per objective, a transport channel's
    top objects per (objective, channel).

    Empty when the job asks for no forward pass. A pass Mitsuba could not push is reported,
    never written as a black image.
    """
    if not job.wants_forward:
        return []
    if not single_pass(buffer.provenance):
        progress.note(
            "no forward or transport layers: this buffer is a shard, an objective task or the "
            "mean of several batches or shards; those are rendered by single-batch runs only "
            "(docs/farm.md)"
        )
        return []
    path = buffer_path.with_name(FORWARD_NAME)
    if not path.exists():  # a FIFO or a folder there is refused by read_forward, by name
        raise SpecError(
            f"the job asks for forward channels but {path.name} is missing",
            where=str(path),
            hint="re-run 'sensaov run' (it writes the buffer and its forward images together)",
        )
    data = read_forward(path)
    check_belongs(data, buffer, path)
    common = {"buffer": str(buffer_path), "forward_file": str(path), "camera": "objective"}
    layers = []
    for f in forward_views(buffer, data):
        if f.data is None:
            progress.note(f"warning: no layer forward.{f.name}: Mitsuba failed: {f.failure}")
            continue
        meta = {**common, **_meta(f.keys, f.direction, f.seed, f.unverified), "kind": "forward"}
        meta.update(original_name=f"forward.{f.name}", scale_group=f"forward/{f.name}",
                    aliases=json.dumps(list(f.aliases)))  # fmt: skip
        layers.append(SensitivityLayer("forward", f.name, f.data, meta))
    for t in transport_views(buffer, data):
        meta = {**common, **_meta(t.keys, t.direction, t.seed, t.unverified), "kind": "transport"}
        meta.update(
            original_name=f"{t.objective}.{t.name}",
            scale_group=f"{t.objective}/{_group(job, t.source, t.name)}",
            aliases=json.dumps(list(t.aliases)),
            forward_sum=repr(t.forward_sum),
            reverse=repr(t.reverse),
            duality_residual=repr(t.residual),
            duality_tolerance=repr(t.tolerance),
            duality="agrees" if t.agrees else "EXCEEDS TOLERANCE: do not trust this layer",
        )
        layers.append(SensitivityLayer(t.objective, t.name, t.data, meta))
    return layers


def _group(job: JobSpec, source: str, name: str) -> str:
    """A transport channel's layers share their channel's scale; an entry's has its own."""
    match = re.match(r"channels\[(\d+)\]", source)
    if match and int(match.group(1)) < len(job.channels):
        return job.channels[int(match.group(1))].name
    return name


def _meta(keys: tuple[str, ...], direction: str, seed: int, unverified: tuple[str, ...]) -> dict:
    return {
        "keys": json.dumps(list(keys)),
        "direction": direction,
        "seed": str(seed),
        "encoding": "none (linear)",
        "unverified": json.dumps(list(unverified)),
    }
