"""Shards of one job into one buffer: the spp-weighted mean, and the shards' statistics (§7).

``sensaov run --shard i/n`` renders batch i-1 of the job's n-batch plan (render/adjoint.py), so
the merge of n shards is the estimate one run with ``render.batches: n`` gives, standard errors
included (each shard is a batch). Shards may also split objectives (``--objective``): every
(shard, objective) pair must be present exactly once. Anything else is refused with the reason:
a shard whose samples or seed are not its batch's in the plan, one rendered by another Mitsuba,
Dr.Jit or variant than the others, and (pipeline/merge.py) a primal that is not the one the
shard recorded writing (:func:`pixels_digest`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import ParamRecord, Repair, SensitivityBuffer
from sensaov_cli.buffer.statistics import combine_batches
from sensaov_cli.errors import MergeError

# How bad a label is, for the merged record: the worst any shard found (no_gradient apart).
_SEVERITY = ("verified", "unverified", "suspect", "biased")
MAX_SHARDS = 1 << 20  # far above any farm; a count beyond it is a damaged file
_HINT = "the file is not a shard as 'sensaov run --shard I/N' writes it: run that shard again"
# What renders a shard: shards made by other builds or variants are not batches of one estimate.
RENDERED_BY = ("mitsuba_version", "drjit_version", "variant")
PRIMAL = "primal"  # provenance: {"file": its name, "sha256": pixels_digest of what was written}


def derived_seed(seed: int, purpose: str, index: int) -> int:
    """A reproducible 31-bit seed for (seed, purpose, index), independent of its neighbours."""
    tag = int.from_bytes(purpose.encode()[:8].ljust(8, b"\0"), "little")
    return int(np.random.SeedSequence([seed, tag, index]).generate_state(1)[0]) % 2**31


def batch_plan(spp: int, seed: int, batches: int, first: int = 0) -> list[tuple[int, int]]:
    """(spp, primal seed) of each of ``batches`` independent batches; batch 0 has ``seed``.
    Shard i of n is batch i-1, so a merge of n shards equals a run with ``render.batches: n``.
    ``first``: the plan's batches are numbered from there (render.until's later rounds: the
    same split of spp at seeds no earlier round used)."""
    sizes = [spp // batches + (1 if i < spp % batches else 0) for i in range(batches)]
    numbered = enumerate(sizes, first)
    return [(n, seed if i == 0 else derived_seed(seed, "batch", i)) for i, n in numbered]


def pixels_digest(channels: Mapping[str, np.ndarray]) -> str:
    """sha256 of an image's channels as an EXR stores them (names, shapes, float32 bits): what a
    buffer records of the primal written with it, so a primal put in its place is recognised.
    The file's bytes cannot serve: its header carries the buffer's provenance, this included."""
    digest = hashlib.sha256()
    for name in sorted(channels):
        data = np.ascontiguousarray(channels[name], np.float32)
        digest.update(f"{name}\0{data.shape}\0".encode())
        digest.update(data.tobytes())
    return digest.hexdigest()


@dataclass(frozen=True)
class ShardTask:
    """What a shard's provenance says it holds, as merge reads it."""

    index: int  # 1..count
    count: int
    spp: int
    job_spp: int
    seed: int  # primal_seed
    job_seed: int  # the job's render.seed, the plan's batch 0
    objectives: tuple[str, ...]  # the whole job's, in job order
    primal_digest: str  # pixels_digest of the primal the shard wrote


@dataclass(frozen=True)
class Shard:
    path: Path
    buffer: SensitivityBuffer
    task: ShardTask


def shard_task(path: Path, provenance: Mapping[str, Any]) -> ShardTask:
    """What merge reads of a shard's provenance, checked: a buffer made without --shard is
    refused, and so is a value missing, of another type or out of range (it would end in an
    internal error, or in a shard silently left out of, or over-weighted in, the mean)."""
    task = _field(path, provenance, "task", dict)
    shard = task.get("shard")
    if shard is None:
        raise MergeError("not a shard (made without --shard)", where=str(path))
    if not isinstance(shard, dict):
        raise _bad(path, "task.shard", shard, "a mapping {index, count}")
    count = _integer(path, shard, "count", "task.shard.count", 1, MAX_SHARDS)
    index = _integer(path, shard, "index", "task.shard.index", 1, count)
    spp = _integer(path, provenance, "spp", "spp", 1, 2**32 - 1)
    job_spp = _integer(path, provenance, "job_spp", "job_spp", 1, 2**32 - 1)
    seed = _integer(path, provenance, "primal_seed", "primal_seed", 0, 2**32 - 1)
    job = _field(path, provenance, "job", dict)
    job_seed = _integer(path, _field(path, job, "render", dict), "seed", "job.render.seed", 0,
                        2**32 - 1)  # fmt: skip
    objectives = _field(path, job, "objectives", list)
    names = [entry.get("name") if isinstance(entry, dict) else None for entry in objectives]
    if not names or not all(isinstance(name, str) for name in names):
        raise _bad(path, "job.objectives", objectives, "a list of objectives with names")
    size = provenance.get("resolution")
    if not (isinstance(size, list) and len(size) == 2 and all(_is_int(n, 1) for n in size)):
        raise _bad(path, "resolution", size, "[width, height]")
    digest = _field(path, provenance, PRIMAL, dict).get("sha256")
    if not (isinstance(digest, str) and len(digest) == 64):
        raise _bad(path, "primal.sha256", digest, "the sha256 of the shard's primal")
    return ShardTask(index, count, spp, job_spp, seed, job_seed, tuple(map(str, names)), digest)


def _field(path: Path, mapping: Mapping[str, Any], key: str, kind: type) -> Any:
    value = mapping.get(key)
    if not isinstance(value, kind):
        raise _bad(path, key, value, "a mapping" if kind is dict else "a list")
    return value


def _integer(
    path: Path, mapping: Mapping[str, Any], key: str, shown: str, least: int, most: int
) -> int:
    value = mapping.get(key)
    if not isinstance(value, int) or not _is_int(value, least, most):
        raise _bad(path, shown, value, f"an integer from {least} to {most}")
    return value


def _is_int(value: Any, least: int, most: int = 2**63) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and least <= value <= most


def _bad(path: Path, key: str, value: Any, expected: str) -> MergeError:
    shown = "missing" if value is None else f"{type(value).__name__} {str(value)[:40]!r}"
    return MergeError(f"provenance {key} is {shown}, not {expected}", where=str(path), hint=_HINT)


def merge_shards(shards: Sequence[Shard]) -> SensitivityBuffer:
    """The merged buffer; :class:`MergeError` (one line, exit 2) if the shards do not fit."""
    if len(shards) < 1:
        raise MergeError("no shards given")
    _check_alike(shards)
    first = shards[0]
    count = first.task.count
    job_objectives = list(first.task.objectives)
    by_index: dict[int, list[Shard]] = {}
    for shard in shards:
        by_index.setdefault(shard.task.index, []).append(shard)
    missing = sorted(set(range(1, count + 1)) - set(by_index))
    if missing:
        raise MergeError(
            f"missing shard(s) {', '.join(f'{i}/{count}' for i in missing[:8])}",
            where=str(first.path.parent),
            hint="run them ('sensaov run JOB --shard I/N') or list every shard file",
        )
    indices = [by_index[i] for i in range(1, count + 1)]
    parts = [_one_index(files, job_objectives, i, count) for i, files in enumerate(indices, 1)]
    merged_grads, merged_values, spp = zip(*parts, strict=True)
    seeds = [files[0].task.seed for files in indices]
    _check_plan(shards)
    grads, objective_values, statistics = combine_batches(
        first.buffer.keys, first.buffer.values, merged_grads, merged_values, spp, seeds, "shards"
    )
    records = {o.name: o for s in shards for o in s.buffer.objectives}
    objectives = tuple(
        replace(records[name], value=objective_values[name]) for name in job_objectives
    )
    params = _merged_records(shards, grads)
    return SensitivityBuffer(
        provenance=_provenance(shards, sum(spp)),
        objects=first.buffer.objects,
        params=params,
        objectives=objectives,
        values=dict(first.buffer.values),
        grads=grads,
        statistics=statistics,
        repairs=_merged_repairs(params, indices, spp),
    )


def _check_plan(shards: Sequence[Shard]) -> None:
    """Each shard holds the samples and seed of its batch in the job's plan (batch_plan): a
    shard that claims more samples than it rendered would weigh more in the mean, and shrink
    the standard errors, silently; one at another seed is not the batch the merge stands for."""
    for shard in shards:
        task, provenance = shard.task, shard.buffer.provenance
        job_render = provenance["job"]["render"]  # checked by shard_task: a mapping
        if job_render.get("spp") != task.job_spp:
            raise MergeError(
                f"provenance job_spp {task.job_spp} is not its job's render.spp "
                f"{job_render.get('spp')!r}",
                where=str(shard.path),
                hint=_HINT,
            )
        spp, seed = batch_plan(task.job_spp, task.job_seed, task.count)[task.index - 1]
        if (task.spp, task.seed) != (spp, seed):
            said = f"{task.spp} spp at seed {task.seed}"
            raise MergeError(
                f"shard {task.index}/{task.count} claims {said}; the job's plan "
                f"({task.job_spp} spp in {task.count} batches) renders it with {spp} spp at "
                f"seed {seed}",
                where=str(shard.path),
                hint="its provenance was changed, or it is not this plan's shard: run it again",
            )


def _check_alike(shards: Sequence[Shard]) -> None:
    first = shards[0]
    seen: set[Path] = set()
    for shard in shards:
        where = str(shard.path)
        resolved = shard.path.resolve()
        if resolved in seen:
            raise MergeError("the same file is given twice", where=where)
        seen.add(resolved)
        for field, what in (("scene_fingerprint", "scene"), ("job_hash", "job")):
            if shard.buffer.provenance.get(field) != first.buffer.provenance.get(field):
                raise MergeError(
                    f"another {what} than {first.path.name} ({field} differs)", where=where
                )
        # The job's paths are absolute (nodes mount the project elsewhere), its render is not.
        if shard.buffer.provenance["job"].get("render") != first.buffer.provenance["job"].get(
            "render"
        ):
            raise MergeError(f"another job.render than {first.path.name}", where=where)
        for field in RENDERED_BY:
            mine, theirs = shard.buffer.provenance.get(field), first.buffer.provenance.get(field)
            if not isinstance(mine, str):
                raise _bad(shard.path, field, mine, "a string")
            if mine != theirs:
                raise MergeError(
                    f"rendered with {field} {mine!r}, {first.path.name} with {theirs!r}: "
                    "shards of one merge are batches of one estimate",
                    where=where,
                    hint="render every shard with the same Mitsuba, Dr.Jit and variant",
                )
        if shard.task.count != first.task.count:
            raise MergeError(
                f"shard of {shard.task.count}, {first.path.name} is a shard of {first.task.count}",
                where=where,
            )
        if shard.buffer.keys != first.buffer.keys or shard.buffer.objects != first.buffer.objects:
            raise MergeError(f"other parameters or objects than {first.path.name}", where=where)
        for key in first.buffer.keys:
            if not np.array_equal(shard.buffer.values[key], first.buffer.values[key]):
                raise MergeError(
                    f"parameter {key!r} has another value than in {first.path.name}", where=where
                )


def _one_index(
    files: list[Shard], job_objectives: list[str], index: int, count: int
) -> tuple[dict[str, Mapping[str, np.ndarray]], dict[str, float], int]:
    """One shard's gradients and objective values (its objectives may be in several files)."""
    grads: dict[str, Mapping[str, np.ndarray]] = {}
    values: dict[str, float] = {}
    spps = {f.task.spp for f in files}
    if len(spps) > 1:
        raise MergeError(f"files of shard {index}/{count} disagree on spp: {sorted(spps)}")
    for shard in files:
        for record in shard.buffer.objectives:
            if record.name in grads:
                raise MergeError(
                    f"shard {index}/{count} of objective {record.name!r} is given twice",
                    where=str(shard.path),
                )
            grads[record.name] = shard.buffer.grads[record.name]
            values[record.name] = record.value
    absent = [name for name in job_objectives if name not in grads]
    if absent:
        raise MergeError(
            f"shard {index}/{count} lacks objective(s) {', '.join(map(repr, absent))}",
            where=str(files[0].path.parent),
        )
    return grads, values, spps.pop()


_MIXED_NOTE = (
    "repaired by finite differences in some shards only: the merge mixes in a reverse-mode "
    "gradient known to be wrong"
)


def _merged_records(
    shards: Sequence[Shard], grads: Mapping[str, Mapping[str, np.ndarray]]
) -> tuple[ParamRecord, ...]:
    """Each parameter with the worst label a shard gave it; no_gradient only if the merged
    gradient is 0 for every objective; estimator "mixed" (and biased) where shards differ."""
    merged = []
    for record in shards[0].buffer.params:
        labels = [s.buffer.param(record.key) for s in shards]
        if len({r.estimator for r in labels}) > 1:
            merged.append(replace(record, estimator="mixed", trust="biased", note=_MIXED_NOTE))
            continue
        flowing = any(np.any(grads[name][record.key]) for name in grads)
        if not flowing:
            zero = next((r for r in labels if r.trust == "no_gradient"), None)
            merged.append(zero or replace(record, trust="no_gradient", note="0 in every shard"))
            continue
        rated = [r for r in labels if r.trust in _SEVERITY]
        worst = max(rated, key=lambda r: _SEVERITY.index(r.trust), default=None)
        merged.append(worst or replace(record, trust="unverified", note="not checked"))
    return tuple(merged)


def _merged_repairs(
    params: Sequence[ParamRecord], indices: Sequence[list[Shard]], spp: Sequence[int]
) -> dict[str, Repair]:
    """Per repaired key, every shard's estimates in one record (each shard's seeds are its
    own); the reverse-mode gradients it replaced, spp-weighted like the merged gradients."""
    merged = {}
    for key in (p.key for p in params if p.estimator == "finite-difference"):
        # per shard index: objective -> the record of the file that rendered that objective
        parts = [{o.name: f.buffer.repairs[key] for f in files for o in f.buffer.objectives}
                 for files in indices]  # fmt: skip
        firsts = [next(iter(part.values())) for part in parts]
        names = list(parts[0])
        merged[key] = replace(
            firsts[0],
            spp=tuple(n for r in firsts for n in r.spp),
            seeds=tuple(n for r in firsts for n in r.seeds),
            estimates={n: np.concatenate([part[n].estimates[n] for part in parts]) for n in names},
            reverse={
                n: np.sum([p[n].reverse[n] * w for p, w in zip(parts, spp, strict=True)], axis=0)
                / sum(spp)
                for n in names
            },
            seconds=sum(r.seconds for r in firsts),
        )
    return merged


_RECORDED = ("task", "spp", "created_utc", "deterministic")  # of each shard, in merged_from


def _provenance(shards: Sequence[Shard], spp: int) -> dict[str, Any]:
    return dict(
        shards[0].buffer.provenance,
        spp=spp,
        task={"shard": None, "objectives": None},
        # what each shard (one batch of the merge) rendered; per-shard timings do not add up
        batches=[
            {"spp": s.task.spp, "seed": s.task.seed}
            for s in {s.task.index: s for s in shards}.values()
        ],
        timings_s={},
        merged_from=[
            {"file": s.path.name} | {k: s.buffer.provenance.get(k) for k in _RECORDED}
            for s in shards
        ],
    )
