"""Pictures that tell the truth: shared robust display scales, display layers, trusted headlines.

Unit tests of the rule (views/channels.py), then two small projected jobs: the demo's Cornell
box from two cameras (Fig. 6) and the interior, whose floor varnish has a biased eta.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.buffer.queries import per_object
from sensaov_cli.job.spec import ChannelSpec
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.outputs.previews import (
    diverging_linear,
    diverging_linear_planes,
    diverging_rgb,
    srgb_uint8,
)
from sensaov_cli.views.channels import (
    FOLLOWER,
    REFERENCE,
    channel_values,
    group_scales,
    robust_scale,
    shared_channel_scale,
    signed_pixels,
)
from sensaov_cli.views.coverage import VisibilityPass, histogram, ranked

from .conftest import sensaov
from .test_cryptomatte import decode_file
from .test_rankings import DEMO_CAMERAS
from .test_report import make_buffer as report_buffer

# --- the rule ------------------------------------------------------------------------------


def test_a_few_pixels_never_set_the_scale() -> None:
    """99 % of the pixels at 0.39 and a lamp of 1 % at 18.7: p95 = 0.39."""
    image = np.full((10, 10), 0.39)
    image[0, 0] = 18.7
    scale = robust_scale({"objective": [image]})
    assert scale.value == pytest.approx(0.39) and scale.clipped == pytest.approx(0.01)
    assert robust_scale({"objective": [image]}, percentile=100).value == pytest.approx(18.7)


def test_zeros_and_what_no_camera_sees_never_count() -> None:
    image = np.zeros((10, 10))
    image[:2, :] = -0.5  # a fifth of the frame painted, the rest nothing
    assert robust_scale({"a": [image]}).value == pytest.approx(0.5)
    empty = robust_scale({"a": [np.zeros((4, 4))]})
    assert (empty.value, empty.painted, empty.clipped) == (0.0, 0, 0.0)


def test_each_camera_weighs_the_same_whatever_its_resolution() -> None:
    small = np.full((2, 2), 1.0)  # 4 pixels at 1
    large = np.full((100, 100), 2.0)  # 10,000 pixels at 2
    scale = robust_scale({"small": [small], "large": [large]}, percentile=40)
    assert scale.value == 1.0  # pooled pixels would give 2: the small camera has half the say
    assert robust_scale({"small": [small], "large": [large]}, percentile=60).value == 2.0
    assert scale.cameras == ("small", "large") and "each camera weighted equally" in scale.rule()


def sorted_rule(magnitudes: list[np.ndarray], percentile: float) -> float:
    """The documented rule written plainly: a stable sort of every camera's |v|, each camera's
    pixels weighted 1/size, the first value whose running weight reaches the percentile."""
    values = np.concatenate(magnitudes)
    weights = np.concatenate([np.full(m.size, 1.0 / m.size) for m in magnitudes])
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order]) / len(magnitudes)
    index = int(np.searchsorted(cumulative, percentile / 100.0 - 1e-12))
    return float(values[order][min(index, values.size - 1)])


def test_the_percentile_by_selection_is_the_documented_sorted_rule() -> None:
    """Cameras of one size take a selection instead of a sort, others merge pre-sorted pixels:
    the value is the sorted rule's, ties and all, for one camera, two of one size and two of
    different sizes."""
    rng = np.random.default_rng(5)
    images = [np.round(rng.normal(size=(30, 40)), 2) for _ in range(2)]  # many ties

    for percentile in (0.5, 50.0, 95.0, 100.0):
        one = robust_scale({"a": images[:1]}, percentile=percentile).value
        two = robust_scale({"a": images[:1], "b": images[1:]}, percentile=percentile).value
        apart = robust_scale({"a": images[:1], "c": [images[1][:7]]}, percentile=percentile)
        magnitudes = [np.abs(image[image != 0]) for image in images]
        assert one == sorted_rule(magnitudes[:1], percentile)
        assert two == sorted_rule(magnitudes, percentile)
        small = np.abs(images[1][:7][images[1][:7] != 0])
        assert apart.value == sorted_rule([magnitudes[0], small], percentile)


def test_the_bracketed_percentile_of_cameras_of_different_sizes_is_the_sorted_rule() -> None:
    """Cameras of different sizes sort only the values between their own percentiles (issue
    23): over 200 random cases (2-4 cameras, sizes 1 to 5,000, ties, scales apart by 10^4, so
    the bracket is sometimes nearly everything) the value is the sorted rule's, bit for bit."""
    rng = np.random.default_rng(11)

    for case in range(200):
        sizes = rng.integers(1, 5000, size=rng.integers(2, 5))
        images = []
        for size in sizes:
            scale = 10.0 ** rng.integers(-4, 1)
            image = (rng.exponential(size=size) * scale).astype(np.float32)
            if case % 2:
                image = np.round(image / scale, 1) * scale  # many ties, some zeros
            images.append(image.reshape(1, -1))
        for percentile in (0.5, 50.0, 95.0, 99.9, 100.0):
            cameras = {str(i): [image] for i, image in enumerate(images)}
            magnitudes = [
                np.abs(im[im != 0]).astype(np.float64) for im in images if np.any(im != 0)
            ]
            expected = sorted_rule(magnitudes, percentile) if magnitudes else 0.0
            assert robust_scale(cameras, percentile=percentile).value == expected, (case, sizes)


def test_the_percentile_of_large_cameras_of_different_sizes_is_the_exact_one() -> None:
    """With millions of pixels the sorted rule's running float sum of 1/n drifts past its
    1e-12 allowance and could pick a neighbour of the percentile where the cumulative weight
    lands on it exactly (an HD and a half-HD camera: 1/4 the pixels). The bracketed rule
    sums only the values inside the bracket: its value is the exact one, checked
    in integers: the smallest v whose cumulative weight reaches p %."""
    rng = np.random.default_rng(0)
    images = [rng.random(1920 * 1080), rng.random(960 * 540)]
    sizes = [image.size for image in images]
    lcm = int(np.lcm.reduce(sizes))
    ordered = [np.sort(image) for image in images]

    def reaches(v: float, percent: int) -> bool:  # 100·Σ k_c·(L/n_c) >= p·C·L, in integers
        counts = [int(np.searchsorted(o, v, side="right")) for o in ordered]
        total = sum(k * (lcm // n) for k, n in zip(counts, sizes, strict=True))
        return 100 * total >= percent * len(sizes) * lcm

    for percent in (95, 99, 90):
        value = robust_scale({"hd": [images[0]], "half": [images[1]]}, percentile=percent).value
        below = max(o[np.searchsorted(o, value) - 1] for o in ordered if o[0] < value)
        assert reaches(value, percent) and not reaches(float(below), percent), percent


def test_colours_of_runs_of_equal_pixels_are_each_pixels_own() -> None:
    """diverging_linear colours each run of equal values once: bit for bit the
    colours of the pixels drawn one at a time, zeros, -0 and clipped values included."""
    rng = np.random.default_rng(6)
    image = np.repeat(rng.normal(size=(8, 5)) * 1e-3, rng.integers(1, 9, size=5), axis=1)
    image[0, :3], image[1, 1], image[2, :] = 0.0, -0.0, 5e-3
    for scale in (2e-3, 0.0):
        alone = np.stack([diverging_linear(np.array([v]), scale)[0] for v in image.ravel()])
        drawn = diverging_linear(image.astype(np.float32), scale)
        assert drawn.shape == (*image.shape, 3) and drawn.dtype == np.float32
        expected = np.stack(
            [diverging_linear(np.array([v], np.float32), scale)[0] for v in image.ravel()]
        )
        assert np.array_equal(drawn.reshape(-1, 3), expected)
        assert np.array_equal(diverging_linear(image, scale).reshape(-1, 3), alone)
        planes = diverging_linear_planes(image, scale, np.float16)  # display layers' form
        assert planes.shape == (3, *image.shape) and all(p.flags.c_contiguous for p in planes)
        assert np.array_equal(
            planes.transpose(1, 2, 0), alone.astype(np.float16).reshape(drawn.shape)
        )


def test_display_colours_stored_as_half_are_the_previews_8_bit_colours() -> None:
    """Display layers are written as half floats: over a million values and every scale kind,
    the sRGB codes of the half colours are the previews' codes, not one of them off by one."""
    values = np.random.default_rng(7).normal(size=1_000_000) * 1e-3
    for scale in (1e-3, 3e-4, 0.0):
        half = diverging_linear(values, scale).astype(np.float16)
        assert np.array_equal(srgb_uint8(half), diverging_rgb(values, scale))


def test_groups_share_one_scale_untrusted_parts_follow() -> None:
    trusted, apart = np.full((4, 4), 0.1), np.full((4, 4), 5.0)
    layers = {
        "a": [("m/objects", REFERENCE, trusted), ("m/objects", FOLLOWER, apart)],
        "b": [("m/objects", REFERENCE, 2 * trusted)],
    }
    shared = group_scales(layers)
    assert shared[("a", "m/objects")] == shared[("b", "m/objects")]  # one scale, every camera
    assert shared[("a", "m/objects")].value == pytest.approx(0.2)  # the 5.0 follows, clipped
    tiles = group_scales(layers, scope="tile")
    assert (tiles[("a", "m/objects")].value, tiles[("b", "m/objects")].value) == (0.1, 0.2)
    assert "only" in tiles[("a", "m/objects")].rule()
    alone = group_scales({"a": [("g", FOLLOWER, apart)]})  # nothing trusted: it sets the scale
    assert alone[("a", "g")].value == 5.0


def test_rgb_layers_by_luminance_or_by_their_sum() -> None:
    rgb = np.ones((2, 2, 3)) * np.array([1.0, 0.0, 0.0])
    assert signed_pixels(rgb, "forward")[0, 0] == pytest.approx(0.2126)
    assert signed_pixels(rgb, "texel")[0, 0] == 1.0


def test_the_shared_channel_scale_reads_the_buffer_and_visibility_only() -> None:
    """What `sensaov view` will call: the biased floor left apart, the wall sets the scale."""
    buf = report_buffer("biased")  # wall 5e-3 sum (verified), floor 0.5 (biased), lamp 4e-2
    objects = buf.objects  # ceiling, floor, lamp, wall
    samples = np.array([[1, 1, 3, 3], [3, 3, 3, 3]], np.int32)  # floor 2 samples, wall 6
    coverage = histogram(samples.reshape(4, 2))
    index, amount = ranked(coverage, (2, 2), 2)
    vis = VisibilityPass(2, 2, 2, objects, None, coverage, index, amount)
    channel = ChannelSpec("objects", "object")
    scale = shared_channel_scale(buf, channel, "brightness", {"cam": vis})
    wall_keys = ["wall.bsdf.reflectance.value"]  # scored by the default, the signed sum
    wall = per_object(buf, "brightness", keys=wall_keys, method="sum")["wall"]
    assert scale.value == pytest.approx(wall)  # not the floor's biased 0.5
    mixed = shared_channel_scale(buf, channel, "brightness", {"cam": vis}, untrusted="include")
    assert mixed.value == pytest.approx(0.5)
    parts = [v.part for v in channel_values(buf, (channel,))]
    assert parts == ["trusted", "untrusted"]


# --- the demo's Cornell box from two cameras ----------------------------------------------


def layers_of(path: Path) -> tuple[dict[str, np.ndarray], dict[str, dict[str, str]]]:
    """Channels, and each sensitivity layer's metadata by its final name."""
    channels, header = read_exr(path)
    by_key: dict[str, dict[str, str]] = {}
    for key, value in header.items():
        parts = key.split("/")
        if key.startswith("sensaov/") and len(parts) == 3:
            by_key.setdefault(parts[1], {})[parts[2]] = value
    return channels, {meta["name"]: meta for meta in by_key.values() if "name" in meta}


def data_of(channels: dict[str, np.ndarray], meta: dict[str, str]) -> np.ndarray:
    names = [f"{meta['name']}.{c}" for c in meta["channels"].split(",")]
    return channels[names[0]] if len(names) == 1 else np.stack([channels[n] for n in names], -1)


@pytest.fixture(scope="module")
def demo(job_writer: Callable[..., Path]) -> Path:
    channels = [
        {"name": "objects", "kind": "object"},
        {"name": "types", "kind": "type"},
        {"name": "transport", "kind": "transport", "top": 2},
    ]
    forward = [{"name": "light", "object": "light"}]
    # Labels, not repairs, are read here: a repair would make the biased ones trusted
    # (tests/test_repairs.py), so this job repairs nothing.
    job = job_writer("display", inspection_cameras=DEMO_CAMERAS, channels=channels,
                     forward=forward, repair={"budget": 0})  # fmt: skip
    assert sensaov("run", "-q", str(job)).returncode == 0
    done = sensaov("project", "-q", str(job), "--png")
    assert done.returncode == 0, done.stderr
    return job


def test_one_scale_per_channel_in_every_camera_and_legend(demo: Path) -> None:
    """Fig. 6: `mean_luma.objects` has one scale in `objective` and `overhead`, in the EXRs'
    metadata and in both previews' legends."""
    out = demo.parent / "out"
    scales = {}
    for camera in ("objective", "overhead"):
        _, meta = layers_of(out / f"{camera}.exr")
        scales[camera] = meta["mean_luma.objects"]["display_scale"]
        assert meta["mean_luma.objects"]["display_scope"] == "shared"
        assert json.loads(meta["mean_luma.objects"]["display_cameras"]) == ["objective", "overhead"]
        types = {m["display_scale"] for n, m in meta.items() if ".types_" in n}
        assert len(types) == 1  # the passes of one channel share its scale
        manifest = json.loads((out / "previews" / f"{camera}.json").read_text())
        (entry,) = [e for e in manifest["files"] if e.get("pass_name") == "objects"
                    and e["objective"] == "mean_luma"]  # fmt: skip
        assert entry["notes"][0].startswith(f"shared scale ±{float(scales[camera]):.3g}: p95")
        assert entry["notes"][1].startswith("clipped: ")
    assert scales["objective"] == scales["overhead"]


def test_the_scale_is_the_documented_rule_over_every_camera(demo: Path) -> None:
    """Recomputed from the files alone: p95 of |v| over the non-zero pixels of both cameras."""
    out = demo.parent / "out"
    pixels: dict[str, list[np.ndarray]] = {}
    recorded = set()
    for camera in ("objective", "overhead"):
        channels, meta = layers_of(out / f"{camera}.exr")
        pixels[camera] = [data_of(channels, meta["mean_luma.objects"])]
        recorded.add(float(meta["mean_luma.objects"]["display_scale"]))
    assert recorded == {robust_scale(pixels).value}


def test_a_farm_task_of_one_camera_derives_the_same_scales(demo: Path, tmp_path: Path) -> None:
    out = demo.parent / "out"
    _, before = layers_of(out / "overhead.exr")
    shutil.copy(out / "overhead.exr", tmp_path / "overhead.exr")
    done = sensaov("project", "-q", str(demo), "--camera", "overhead")
    assert done.returncode == 0, done.stderr
    _, after = layers_of(out / "overhead.exr")
    assert {n: m["display_scale"] for n, m in before.items()} == {
        n: m["display_scale"] for n, m in after.items()
    }


def test_a_per_tile_scale_is_only_on_request_and_labelled(demo: Path, tmp_path: Path) -> None:
    """`views: {scale: tile}` (the same buffer: views are not part of the run version) gives
    each camera its own scale, the rule over that camera alone, said in EXR and legends."""
    data = yaml.safe_load(demo.read_text())
    floor = {"name": "floor_only", "resolution": [16, 16], "vis_spp": 4, "fov": 30,
             "look_at": {"origin": [0.0, 0.2, 0.3], "target": [0.0, -1.0, 0.3],
                         "up": [0.0, 0.0, -1.0]}}  # fmt: skip
    data.update(views={"scale": "tile"}, output=str(tmp_path / "out"),
                inspection_cameras=[*data["inspection_cameras"], floor])  # fmt: skip
    tiled = tmp_path / "job.yaml"
    tiled.write_text(yaml.safe_dump(data, sort_keys=False))
    buffer = demo.parent / "out" / "buffer.npz"
    done = sensaov("project", "-q", str(tiled), "--buffer", str(buffer), "--png")
    assert done.returncode == 0, done.stderr
    scales = {}
    for camera in ("objective", "overhead", "floor_only"):
        channels, meta = layers_of(tmp_path / "out" / f"{camera}.exr")
        m = meta["mean_luma.objects"]
        assert m["display_scope"] == "tile" and json.loads(m["display_cameras"]) == [camera]
        scales[camera] = float(m["display_scale"])
        assert scales[camera] == robust_scale({camera: [data_of(channels, m)]}).value
        manifest = json.loads((tmp_path / "out" / "previews" / f"{camera}.json").read_text())
        (entry,) = [e for e in manifest["files"] if e.get("pass_name") == "objects"
                    and e["objective"] == "mean_luma"]  # fmt: skip
        assert entry["notes"][0].startswith(f"per-tile scale ±{scales[camera]:.3g}: p95")
        assert entry["notes"][0].endswith(f"non-zero pixels of {camera} only")
    # objective and overhead both land on the back wall's value; the floor alone does not,
    # and keeps its own number where the shared rule gives every camera one
    assert scales["floor_only"] not in (scales["objective"], scales["overhead"])


def test_every_raw_layer_has_a_display_layer_an_artist_sees(demo: Path) -> None:
    """Beside each raw layer, its picture: the previews' colours at the display scale, bright
    enough to see (>= 10 % of the visible pixels above 0.1 in [0, 1]); raw values untouched."""
    out = demo.parent / "out"
    for camera in ("objective", "overhead"):
        channels, meta = layers_of(out / f"{camera}.exr")
        visible = channels["A"] > 0
        raw = {n: m for n, m in meta.items() if m.get("kind") != "display"}
        assert any(n.startswith("forward.") for n in raw) == (camera == "objective")
        for name, m in raw.items():
            shown = meta[m["display_layer"]]
            assert shown["display_of"] == m["original_name"]
            colours = data_of(channels, shown)
            assert colours.shape[-1] == 3 and colours.dtype == np.float16  # a picture: half
            share = float((colours.max(axis=-1) > 0.1)[visible].mean())
            assert share >= 0.1, (camera, name, share)
            values = signed_pixels(data_of(channels, m), m.get("kind", ""))
            expected = diverging_linear(values, float(m["display_scale"]))
            painted = values != 0
            # half's rounding (2^-11 relative, 2^-25 below its normal range) and not more: the
            # previews' 8-bit sRGB codes come out the same
            np.testing.assert_allclose(
                colours[painted], expected[painted], rtol=2**-11, atol=2**-25
            )
            np.testing.assert_array_equal(
                srgb_uint8(colours[painted]), srgb_uint8(expected[painted])
            )


def test_transport_layers_are_not_written_twice(demo: Path) -> None:
    channels, meta = layers_of(demo.parent / "out" / "objective.exr")
    transport = {n: m for n, m in meta.items() if m.get("kind") == "transport"}
    data = [data_of(channels, m).tobytes() for m in transport.values()]
    assert transport and len(set(data)) == len(data)  # no two bit-identical layers


def test_untrusted_parameters_leave_the_headline_layer(demo: Path) -> None:
    """The tall box's roughplastic alpha and eta are biased: its pixels in `objects` hold its
    trusted parameters only, and `objects_untrusted` holds the rest."""
    out = demo.parent / "out"
    buffer = read_buffer(out / "buffer.npz")
    biased = [p.key for p in buffer.params if p.trust == "biased" and "tall_box" in p.owners]
    assert biased
    trusted = [p.key for p in buffer.params if p.trust in ("verified", "no_gradient")]
    expected = per_object(buffer, "mean_luma", keys=trusted, method="sum")["tall_box"]
    apart = per_object(buffer, "mean_luma", keys=biased, method="sum")["tall_box"]
    channels, meta = layers_of(out / "objective.exr")
    names, coverages, _ = decode_file(out / "objective.exr", "CryptoObject")
    full = (names[0] == "tall_box") & (coverages[0] == 1.0)
    assert full.any()
    headline = np.abs(channels["mean_luma.objects.Y"][full])
    np.testing.assert_allclose(headline, abs(expected), rtol=1e-5)
    np.testing.assert_allclose(np.abs(channels["mean_luma.objects_untrusted.Y"][full]),
                               abs(apart), rtol=1e-5)  # fmt: skip
    left = json.loads(meta["mean_luma.objects"]["left_out"])
    assert sorted(left["tall_box"]) == sorted(biased)


# --- the interior: a biased varnish on the floor ----------------------------------------------


@pytest.fixture(scope="module")
def interior(job_writer: Callable[..., Path]) -> Any:
    cameras = [{"name": "corner", "sensor": "corner", "resolution": [32, 32], "vis_spp": 4}]
    job = job_writer("interior_display", scene="interior", inspection_cameras=cameras,
                     channels=[{"name": "objects", "kind": "object"}],
                     objective_camera="sensor", repair={"budget": 0})  # fmt: skip
    assert sensaov("run", "-q", str(job)).returncode == 0
    done = sensaov("project", "-q", str(job), "--png")
    assert done.returncode == 0, done.stderr
    return job.parent / "out"


def test_the_interior_floor_is_not_painted_by_its_biased_varnish(interior: Path) -> None:
    buffer = read_buffer(interior / "buffer.npz")
    floor = [p for p in buffer.params if "floor" in p.owners]
    assert any(p.trust == "biased" for p in floor)
    trusted = [p.key for p in floor if p.trust in ("verified", "no_gradient")]
    sums = per_object(buffer, "mean_luma", keys=trusted, method="sum")  # the default score
    expected = sums["floor"] if trusted else 0.0
    channels, meta = layers_of(interior / "corner.exr")
    names, coverages, _ = decode_file(interior / "corner.exr", "CryptoObject")
    full = (names[0] == "floor") & (coverages[0] == 1.0)
    assert full.any()
    np.testing.assert_allclose(np.abs(channels["mean_luma.objects.Y"][full]), abs(expected),
                               rtol=1e-5, atol=1e-12)  # fmt: skip
    assert (channels["mean_luma.objects_untrusted.Y"][full] != 0).all()  # the part left out
    assert "floor" in json.loads(meta["mean_luma.objects"]["left_out"])
    manifest = json.loads((interior / "previews" / "corner.json").read_text())
    legend = next(e for e in manifest["files"] if e.get("pass_name") == "objects")
    assert any(line.startswith("left out (untrusted") and "floor" in line
               for line in legend["notes"])  # fmt: skip
