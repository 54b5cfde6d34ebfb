"""Forward channels, transport layers and the duality column of ``check``."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from sensaov_cli.buffer.forward_sidecar import read_forward
from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import SpecError
from sensaov_cli.views.channels import forward_views, transport_views
from tests.bad_buffers import write_buffer

from .conftest import sensaov, write_job

REGION = {"name": "region", "type": "region_luminance", "region": [0.3, 0.2, 0.7, 0.6]}
GREEN = "green.reflectance.value"


@pytest.fixture(scope="session")
def cbox_forward(job_writer: Callable[..., Path]) -> tuple[Path, subprocess.CompletedProcess[str]]:
    job = job_writer(
        "forward_cbox",
        # several batches: forward passes are pushed once per batch at its own seeds (two keep
        # it cheap; test_default_errors runs the default's eight)
        render={"spp": 16, "max_depth": 6, "seed": 0, "resolution": [24, 24], "batches": 2},
        objectives=[{"name": "mean_luma", "type": "mean_luminance"}, REGION],
        forward=[
            {"name": "green_wall", "select": "green.*", "transport": True},
            {"name": "light", "object": "light", "direction": "ones"},
        ],
        channels=[{"name": "objects", "kind": "object"}, {"name": "tr", "kind": "transport"}],
    )
    done = sensaov("run", str(job))
    assert done.returncode == 0, done.stderr
    return job, done


def _load(job: Path) -> tuple[SensitivityBuffer, object]:
    out = job.parent / "out"
    return read_buffer(out / "buffer.npz"), read_forward(out / "forward.npz")


def test_run_reports_the_cost_of_every_forward_pass(cbox_forward: tuple) -> None:
    _, done = cbox_forward
    assert "forward 'green_wall' (forward[0]):" in done.stderr
    assert "x one backward pass" in done.stderr


def test_forward_channel_matches_same_seed_central_differences(cbox_forward: tuple) -> None:
    """J·v of the green wall's reflectance against (I(θ+εv) − I(θ−εv)) / 2ε at its seeds: the
    run has the default batches, each pushed at its own (spp, gradient seed), spp-weighted."""
    from sensaov_cli.job.load import load_job
    from sensaov_cli.render.adjoint import gradient_seed, render_primal
    from sensaov_cli.render.loading import assign, load_job_scene
    from sensaov_cli.render.visibility import trace

    job, _ = cbox_forward
    buffer, data = _load(job)
    view = next(v for v in forward_views(buffer, data) if v.name == "green_wall")
    assert view.keys == (GREEN,) and view.data is not None
    loaded = load_job_scene(load_job(job))
    theta = buffer.value(GREEN)
    eps = 1e-2
    batches = [(b["spp"], b["seed"]) for b in buffer.provenance["batches"]]
    assert len(batches) == 2 and view.seed == gradient_seed(batches[0][1], 0)
    total = sum(spp for spp, _ in batches)
    sides = []
    for sign in (1, -1):
        assign(loaded, GREEN, theta + sign * eps * theta)
        sides.append(
            sum(
                np.array(render_primal(loaded, spp, gradient_seed(seed, 0)), np.float64)[..., :3]
                * (spp / total)
                for spp, seed in batches
            )
        )
    assign(loaded, GREEN, theta)
    central = (sides[0] - sides[1]) / (2 * eps)
    forward = view.data.astype(np.float64)
    # Non-zero only where a path at this seed meets the material (the same-seed difference is
    # exactly 0 elsewhere). Below float32's resolution of a pixel the difference reads 0 while
    # J·v does not: one pixel at 2e-10 measured, so "zero" is 1e-6 of the largest value.
    touched = np.abs(central).sum(axis=2) > 0
    assert np.abs(forward[~touched]).max(initial=0) < 1e-6 * np.abs(forward).max()
    assert (np.abs(forward).sum(axis=2) > 0)[touched].mean() > 0.99
    # The image is smooth in a diffuse reflectance: the difference's error is O(ε²) plus float32
    # cancellation (~1e-7 / 2ε of a pixel): 1.8e-4 measured at ε = 1e-2, so 1e-3.
    error = np.linalg.norm(forward - central) / np.linalg.norm(central)
    assert error < 1e-3, error
    # It lands where the wall is: brightest on the wall itself, through indirect light elsewhere.
    seen = trace(loaded.mi, loaded.scene, loaded.sensor, buffer.objects, 4, seed=0)
    wall = seen.rank_index[..., 0] == buffer.objects.index("right_wall")
    luminance = np.abs(forward).sum(axis=2)
    assert luminance[wall].mean() > 3 * luminance[~wall].mean() > 0


def test_every_transport_layer_sums_to_the_buffer(cbox_forward: tuple) -> None:
    job, _ = cbox_forward
    buffer, data = _load(job)
    views = transport_views(buffer, data)
    # green_wall for both objectives, and the top 3 objects of each objective
    assert len(views) == 2 + 3 * 2
    assert {v.objective for v in views} == {"mean_luma", "region"}
    for view in views:
        assert view.residual <= 1e-4, (view.objective, view.name, view.residual)
        assert abs(view.reverse) > 0 and view.agrees


def test_project_writes_forward_and_transport_layers(cbox_forward: tuple) -> None:
    job, _ = cbox_forward
    done = sensaov("project", str(job), "--png")
    assert done.returncode == 0, done.stderr
    out = job.parent / "out"
    exr = OpenEXR.File(str(out / "objective.exr"))
    channels = exr.channels()
    assert channels["forward.green_wall"].pixels.shape == (24, 24, 3)
    transport = channels["mean_luma.transport_green_wall.Y"].pixels
    assert transport.shape == (24, 24) and np.abs(transport).sum() > 0
    header = {k: v for k, v in exr.header().items() if k.startswith("sensaov/")}
    assert sum(v == "agrees" for k, v in header.items() if k.endswith("/duality")) == 8
    assert (out / "previews" / "objective" / "forward.green_wall.png").is_file()


def test_a_sidecar_of_another_buffer_is_refused(cbox_forward: tuple, tmp_path: Path) -> None:
    job, _ = cbox_forward
    shutil.copytree(job.parent / "out", tmp_path / "out")
    buffer = read_buffer(tmp_path / "out" / "buffer.npz")
    provenance = {**buffer.provenance, "created_utc": "2000-01-01T00:00:00+00:00"}
    stale = dataclasses.replace(buffer, provenance=provenance)
    write_buffer(tmp_path / "out" / "buffer.npz", stale)
    done = sensaov("project", str(job), "--buffer", str(tmp_path / "out" / "buffer.npz"))
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "belongs to another buffer" in done.stderr


def test_check_passes_and_fails_loudly_on_a_corrupted_gradient(
    cbox_forward: tuple, tmp_path: Path
) -> None:
    job, _ = cbox_forward
    keys = ("--key", "light.emitter.radiance.value", "--key", GREEN)
    done = sensaov("check", str(job), "--seeds", "2", "--directions", "1", *keys)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "duality at the buffer's gradient seeds" in done.stdout
    assert done.stdout.count(" agrees") >= 2 + 2 * 2 * 2
    buffer = read_buffer(job.parent / "out" / "buffer.npz")
    grads = {o: dict(g) for o, g in buffer.grads.items()}
    grads["region"][GREEN] = grads["region"][GREEN] * np.float32(1.5)  # corrupted on purpose
    write_buffer(tmp_path / "buffer.npz", dataclasses.replace(buffer, grads=grads))
    done = sensaov("check", str(job), "--seeds", "2", "--directions", "1", *keys,
                   "--buffer", str(tmp_path / "buffer.npz"))  # fmt: skip
    assert done.returncode == 1
    lines = [line for line in done.stdout.splitlines() if "BUFFER DISAGREES" in line]
    assert lines and all("region" in line and GREEN in line for line in lines)


def test_indirect_only_wall_paints_the_objects_it_lights(tmp_path: Path) -> None:
    """scenes/interior's front wall is behind the camera: seen nowhere, felt everywhere."""
    from sensaov_cli.job.load import load_job
    from sensaov_cli.render.loading import load_job_scene
    from sensaov_cli.render.visibility import trace

    forward = [{"name": "front_wall", "object": "front_wall", "transport": True}]
    job = write_job(tmp_path, "interior", forward=forward, channels=[])
    done = sensaov("run", "-q", str(job))
    assert done.returncode == 0, done.stderr
    buffer, data = _load(job)
    (view,) = transport_views(buffer, data)
    assert view.residual <= 1e-4 and view.forward_sum > 0
    loaded = load_job_scene(load_job(job))
    seen = trace(loaded.mi, loaded.scene, loaded.sensor, buffer.objects, 4, seed=0)
    assert "front_wall" not in seen.visible_objects
    first = seen.rank_index[..., 0]
    lit = []
    for index, name in enumerate(buffer.objects):
        pixels = first == index
        if pixels.sum() >= 10 and view.data[pixels].mean() > 0.02 * np.abs(view.data).max():
            lit.append(name)
    assert len(lit) >= 3, lit  # walls, floor, furniture: the light it bounces lands on them
    assert (view.data > 0).mean() > 0.5


def test_forward_entries_are_validated(tmp_path: Path) -> None:
    from sensaov_cli.job.load import load_job

    both = [{"name": "a", "select": "*", "type": "reflectance"}]
    with pytest.raises(SpecError, match="exactly one of select, object or type"):
        load_job(write_job(tmp_path / "a", forward=both))
    with pytest.raises(SpecError, match="top"):
        load_job(write_job(tmp_path / "b", channels=[{"name": "o", "kind": "object", "top": 2}]))
    reserved = [{"name": "forward", "type": "mean_luminance"}]
    with pytest.raises(SpecError, match="reserved for forward channels"):
        load_job(write_job(tmp_path / "c", objectives=reserved))
    nothing = sensaov("run", str(write_job(tmp_path / "d", forward=[{"name": "x", "object": "x"}])))
    assert nothing.returncode == 2 and "forward[0].object" in nothing.stderr
    assert not (tmp_path / "d" / "out" / "buffer.npz").exists()


def test_delta_lobe_parameters_keep_duality(tmp_path: Path) -> None:
    """glass_table's clear glass goes through Mitsuba's path integrator, forward and backward."""
    forward = [{"name": "glass", "select": "clear_glass.*", "transport": True}]
    job = write_job(
        tmp_path, "corpus/glass_table", scene_args={"ior": "1.5"}, forward=forward, channels=[],
        objectives=[{"name": "mean_luma", "type": "mean_luminance"}, REGION],
    )  # fmt: skip
    done = sensaov("run", "-q", str(job))
    assert done.returncode == 0, done.stderr
    buffer, data = _load(job)
    assert data.passes[0].integrators == ("path",)
    views = transport_views(buffer, data)
    assert len(views) == 2
    for view in views:  # 2.3e-3 for the region before path's own render_forward was used
        assert view.residual <= 1e-4 and view.forward_sum > 0, (view.objective, view.residual)


def test_progress_counts_every_pass_and_provenance_times_them(cbox_forward: tuple) -> None:
    """100 % comes at the end, after the forward passes (it came after 3 of 7); the buffer's
    wall time and timings include the forward passes."""
    job, done = cbox_forward
    lines = done.stderr.splitlines()
    percents = [
        (i, int(line[10:-1])) for i, line in enumerate(lines) if line.startswith("Progress:")
    ]
    last_pass = max(i for i, line in enumerate(lines) if "forward pass" in line)
    assert [p for _, p in percents] == sorted(p for _, p in percents)
    assert [i for i, p in percents if p == 100] and min(
        i for i, p in percents if p == 100
    ) > last_pass
    assert len(percents) >= 8  # a line per stage: primal, backward passes, forward passes, write
    buffer, _ = _load(job)
    timings = buffer.provenance["timings_s"]
    forward = [seconds for stage, seconds in timings.items() if stage.startswith("forward_")]
    assert len(forward) >= 4
    primal = sum(seconds for stage, seconds in timings.items() if stage.startswith("primal"))
    assert buffer.provenance["wall_time_s"] >= sum(forward) + primal
