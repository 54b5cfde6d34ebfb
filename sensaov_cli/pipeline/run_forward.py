"""Wire ``sensaov run``'s forward passes: the job's forward channels and transport layers (§4, §7).

Groups are resolved before anything renders (:func:`plan_forward`). After the backward passes,
:func:`run_forward` pushes each group once per seed it needs: a forward channel at the first
objective's gradient seed, a transport layer at its own objective's gradient seed, the seed the
buffer's gradient was computed at, so that the layer's duality check can hold to float32
rounding. Identical (keys, direction, seed) passes render once.
"""

from __future__ import annotations

import dataclasses
import datetime
import sys
from dataclasses import dataclass

import numpy as np

from sensaov_cli.buffer.forward_sidecar import (
    ForwardData,
    ForwardLayer,
    ForwardPass,
    ties_of,
)
from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.job.spec import ChannelSpec, JobSpec
from sensaov_cli.outputs.provenance import made_by
from sensaov_cli.progress import Progress
from sensaov_cli.render.forward import adjoint_images, forward_image
from sensaov_cli.render.loading import LoadedScene
from sensaov_cli.render.objectives import Objective
from sensaov_cli.views.transport import (
    direction_values,
    group_keys,
    top_objects,
    transport_views,
)


@dataclass(frozen=True)
class _Group:
    name: str
    keys: tuple[str, ...]
    direction: str
    transport: bool
    source: str


def plan_forward(job: JobSpec, loaded: LoadedScene) -> list[_Group]:
    """The job's forward entries as key groups; an entry that selects nothing fails here."""
    groups = []
    for index, spec in enumerate(job.forward):
        where = f"forward[{index}]"
        keys = group_keys(loaded.selected, spec, where)
        groups.append(_Group(spec.name, keys, spec.direction, spec.transport, where))
    return groups


def forward_bound(job: JobSpec, objectives: int) -> int:
    """The most forward passes the job can need with ``objectives`` objectives: one per forward
    entry, one per other objective for a transport entry, a transport channel's top objects for
    every objective (fewer when objects score 0 or passes coincide: skipped after the run)."""
    entries = sum(objectives if spec.transport else 1 for spec in job.forward)
    tops = sum(c.top * objectives for c in job.channels if c.kind == "transport")
    return entries + tops


def run_forward(
    job: JobSpec,
    loaded: LoadedScene,
    objectives: list[Objective],
    buffer: SensitivityBuffer,
    primal: np.ndarray,
    progress: Progress,
) -> ForwardData | None:
    """Render every forward pass the job asks for; None when it asks for none."""
    if not job.wants_forward:
        return None
    seeds = {o.name: o.grad_seed for o in buffer.objectives}
    first = buffer.objectives[0].name
    backward_s = progress.timings.get(f"backward_{first}_s", 0.0)
    layers: list[ForwardLayer] = []
    runner = _Passes(loaded, buffer, job, primal.shape, progress, backward_s)
    for group in plan_forward(job, loaded):
        index = runner.get(group, seeds[first])
        layers.append(ForwardLayer("forward", group.name, None, index, group.source))
        if group.transport:
            for objective in seeds:
                index = runner.get(group, seeds[objective])
                name = f"transport_{group.name}"
                layers.append(ForwardLayer("transport", name, objective, index, group.source))
    for position, channel in enumerate(job.channels):
        if channel.kind == "transport":
            layers += _top_layers(runner, buffer, seeds, channel, position)
    data = ForwardData(
        ties=ties_of(buffer),
        provenance=_provenance(job, runner),
        adjoints=adjoint_images(loaded, objectives, primal),
        passes=tuple(runner.passes),
        layers=_unique(layers),
    )
    _warn(data, buffer, progress)
    return data


def _unique(layers: list[ForwardLayer]) -> tuple[ForwardLayer, ...]:
    """One layer per EXR name: a repeat of the same pass is dropped, another pass numbered."""
    kept: dict[tuple[str, str | None, str], ForwardLayer] = {}
    for layer in layers:
        name = layer.name
        while (layer.kind, layer.objective, name) in kept:
            if kept[(layer.kind, layer.objective, name)].pass_index == layer.pass_index:
                break
            name += "_2"
        else:
            kept[(layer.kind, layer.objective, name)] = dataclasses.replace(layer, name=name)
    return tuple(kept.values())


def _top_layers(
    runner: _Passes,
    buffer: SensitivityBuffer,
    seeds: dict[str, int],
    channel: ChannelSpec,
    position: int,
) -> list[ForwardLayer]:
    """``<objective>.<channel>_<object>`` for the channel's top objects of every objective."""
    direction = "value" if channel.weight == "value" else "ones"
    layers = []
    for objective in seeds:
        for name in top_objects(buffer, objective, channel.top, channel.weight):
            keys = tuple(p.key for p in buffer.params if name in p.owners)
            source = f"channels[{position}] (top {channel.top} of {objective})"
            group = _Group(name, keys, direction, True, source)
            index = runner.get(group, seeds[objective])
            layer_name = f"{channel.name}_{name}"
            layers.append(ForwardLayer("transport", layer_name, objective, index, source))
    return layers


class _Passes:
    """Forward passes rendered so far, one per (keys, direction, seed)."""

    def __init__(
        self,
        loaded: LoadedScene,
        buffer: SensitivityBuffer,
        job: JobSpec,
        shape: tuple[int, ...],
        progress: Progress,
        backward_s: float,
    ) -> None:
        self.loaded, self.buffer, self.job, self.shape = loaded, buffer, job, shape
        self.progress, self.backward_s = progress, backward_s
        self.passes: list[ForwardPass] = []
        self.index: dict[tuple[tuple[str, ...], str, int], int] = {}

    def get(self, group: _Group, seed: int) -> int:
        key = (tuple(sorted(group.keys)), group.direction, seed)
        if key in self.index:
            return self.index[key]
        v = direction_values(self.buffer, group.keys, group.direction)
        n = len(self.passes)
        label = f"forward pass {n + 1} '{group.name}' ({len(group.keys)} parameters, seed {seed})"
        with self.progress.stage(f"forward_{n}_s", label):
            result = forward_image(
                self.loaded, v, spp=self.job.render.spp, seed=seed, shape=self.shape,
                deterministic=self.job.render.deterministic,
            )  # fmt: skip
        ratio = result.seconds / self.backward_s if self.backward_s > 0 else float("nan")
        self.progress.note(
            f"forward '{group.name}' ({group.source}): {result.seconds:.2f} s, "
            f"{ratio:.2f}x one backward pass"
        )
        if result.failure:
            self.progress.note(f"warning: Mitsuba cannot push '{group.name}': {result.failure}")
        self.passes.append(
            ForwardPass(
                group.keys,
                group.direction,
                seed,
                result.seconds,
                result.integrators,
                result.failure,
                result.image,
            )  # fmt: skip
        )
        self.index[key] = n
        return n


def _provenance(job: JobSpec, runner: _Passes) -> dict[str, object]:
    return {
        **made_by(" ".join(sys.argv)),
        "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "spp": job.render.spp,
        "max_depth": runner.loaded.prepared.integration.max_depth,
        "backward_s": runner.backward_s,
        "forward_s": [round(p.seconds, 4) for p in runner.passes],
    }


def _warn(data: ForwardData, buffer: SensitivityBuffer, progress: Progress) -> None:
    for view in transport_views(buffer, data):
        if not view.agrees:
            progress.note(
                f"warning: transport layer {view.objective}.{view.name}: duality "
                f"residual {view.residual:.2e} exceeds {view.tolerance:.1e} (layer marked)"
            )
