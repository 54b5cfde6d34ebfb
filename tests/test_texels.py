"""Texel fields: the lookup against Mitsuba's own bitmap, pooling's exact sums (§3, §6)."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from sensaov_cli.views.texels import (
    Pool,
    TextureSampling,
    default_pool,
    footprint,
    lookup,
    pool_field,
    seed_noise,
    texel_weights,
)


def _rotation(degrees: float, scale: tuple[float, float], shift: tuple[float, float]) -> np.ndarray:
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    rotate = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return np.array([[scale[0], 0, shift[0]], [0, scale[1], shift[1]], [0, 0, 1.0]]) @ rotate


SCENE = Path(__file__).parents[1] / "scenes" / "cbox" / "scene.xml"


@pytest.mark.parametrize("filter_type", ["bilinear", "nearest"])
@pytest.mark.parametrize("wrap", ["repeat", "mirror", "clamp"])
def test_lookup_matches_mitsubas_bitmap(mi: ModuleType, filter_type: str, wrap: str) -> None:
    import drjit as dr

    rng = np.random.default_rng(7)
    texels = rng.random((5, 7, 3)).astype(np.float32)
    matrix = _rotation(30.0, (1.7, 0.8), (0.2, -0.1))
    to_uv = mi.ScalarTransform3f(matrix.tolist())
    texture = mi.load_dict(
        {
            "type": "bitmap",
            "bitmap": mi.Bitmap(texels),
            "raw": True,
            "filter_type": filter_type,
            "wrap_mode": wrap,
            "to_uv": to_uv,
        }
    )
    uv = rng.uniform(-1.5, 2.5, (500, 2))
    si = dr.zeros(mi.SurfaceInteraction3f, len(uv))
    si.uv = mi.Point2f(uv[:, 0], uv[:, 1])
    expected = np.array(texture.eval(si)).T
    got = lookup(texels, uv, TextureSampling(filter_type, wrap, matrix))
    assert np.allclose(got, expected, atol=2e-5), np.abs(got - expected).max()


@pytest.mark.parametrize("kind", ["gaussian", "box", "mip"])
@pytest.mark.parametrize("wrap", ["repeat", "mirror", "clamp"])
def test_pooling_conserves_the_sum(kind: str, wrap: str) -> None:
    rng = np.random.default_rng(1)
    field = rng.normal(size=(13, 9, 3)) * (rng.random((13, 9, 1)) < 0.2)
    pooled = pool_field(field, Pool(kind, 2.0, "job"), wrap)
    assert pooled.shape == field.shape
    assert np.allclose(pooled.sum(axis=(0, 1)), field.sum(axis=(0, 1)), rtol=1e-12, atol=1e-12)
    assert np.count_nonzero(pooled) > np.count_nonzero(field)  # it spreads


@pytest.mark.parametrize("wrap", ["repeat", "mirror", "clamp"])
@pytest.mark.parametrize(
    ("kind", "radius"), [("gaussian", 1.0), ("gaussian", 9.0), ("box", 20.0), ("gaussian", 60.0)]
)
def test_long_kernels_pool_by_fft_as_tap_by_tap(
    wrap: str, kind: str, radius: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Kernels past DIRECT_TAPS are applied by FFT: the same field and variance to 1e-13 of
    the largest value, and exactly the same texels left at zero (nothing reaches them), on
    fields sparse, dense and empty, and kernels longer than the texture (wrapping over it)."""
    from sensaov_cli.views import texels as pooling

    rng = np.random.default_rng(5)
    pool = Pool(kind, radius, "job")
    one = np.zeros((120, 90, 2))
    one[3, 80, 1] = 2.5  # one texel: far from it, nothing arrives
    cases = [rng.normal(size=(70, 50, 3)) * (rng.random((70, 50, 3)) < d) for d in (0.002, 0.3)]
    cases += [rng.normal(size=(9, 40, 1)), np.zeros((8, 8, 2)), one]
    for field in cases:
        results = []
        for taps in (10**9, 0):  # every kernel tap by tap, then every kernel by FFT
            monkeypatch.setattr(pooling, "DIRECT_TAPS", taps)
            results.append(
                (pool_field(field, pool, wrap), pooling.pool_variance(field**2, pool, wrap))
            )
        (direct, direct_var), (fourier, fourier_var) = results
        largest = max(float(np.abs(field).max()), 1.0)
        assert np.abs(direct - fourier).max() <= 1e-13 * largest
        assert np.abs(direct_var - fourier_var).max() <= 1e-13 * largest**2
        np.testing.assert_array_equal(direct == 0, fourier == 0)
        np.testing.assert_array_equal(direct_var == 0, fourier_var == 0)
        if field is one and len(pooling._kernel(pool)) < 90:
            assert (direct == 0).any() and (direct != 0).any()  # the zero check has teeth


def test_pooling_reduces_seed_noise_of_a_sparse_estimate() -> None:
    rng = np.random.default_rng(3)
    truth = np.ones((32, 32, 1))

    def estimate() -> np.ndarray:
        hits = rng.random(truth.shape) < 0.25
        return truth * hits / 0.25

    first, second = estimate(), estimate()
    pool = Pool("gaussian", 2.0, "job")
    before = seed_noise(first, second)
    after = seed_noise(pool_field(first, pool, "repeat"), pool_field(second, pool, "repeat"))
    assert after < before / 4


def test_default_pool_grows_as_samples_shrink() -> None:
    many = default_pool(1024, 512 * 512, (64, 64))
    few = default_pool(1, 32 * 32, (256, 256))
    assert many.radius == 1.0 and few.radius > 4.0


def test_painting_averages_owner_samples_only() -> None:
    texels = np.zeros((2, 2, 1))
    texels[0, 1, 0] = 4.0  # row 0 (v < 0.5), column 1 (u > 0.5)
    uv = np.array([[0.75, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.25]], np.float32)
    sample_uv = uv.reshape(1, 1, 4, 2)
    sample_object = np.array([0, 1, 0, -1]).reshape(1, 1, 4)
    sampling = TextureSampling("nearest", "clamp")
    seen_by = footprint((2, 2), sampling, sample_uv, sample_object, np.array([0]))
    painted = seen_by.paint(texels.reshape(4, 1), np.array([1.0]))
    assert painted[0, 0, 0] == pytest.approx(1.0)  # one owner sample of four reads 4
    assert seen_by.seen((2, 2)).tolist() == [[False, True], [True, False]]
    both = footprint((2, 2), sampling, sample_uv, sample_object, np.array([0, 1]))
    assert both.paint(texels.reshape(4, 1), np.array([1.0, 0.5]))[0, 0, 0] == pytest.approx(1.5)


def test_footprint_painting_equals_per_sample_lookups() -> None:
    rng = np.random.default_rng(11)
    texels = rng.normal(size=(5, 6, 3))
    sample_uv = rng.uniform(-0.5, 1.5, (3, 4, 8, 2))
    sample_object = rng.integers(-1, 3, (3, 4, 8))
    sampling = TextureSampling("bilinear", "mirror", _rotation(20.0, (1.3, 0.9), (0.1, 0.0)))
    factor = np.array([2.0, 0.0, -1.0])
    seen_by = footprint((5, 6), sampling, sample_uv, sample_object, np.array([0, 1, 2]))
    painted = seen_by.paint(texels.reshape(30, 3), factor)
    per_sample = lookup(texels, sample_uv.reshape(-1, 2), sampling).reshape(3, 4, 8, 3)
    weight = np.where(sample_object >= 0, factor[np.maximum(sample_object, 0)], 0.0)
    expected = (per_sample * weight[..., None]).mean(axis=2)
    assert np.allclose(painted, expected, atol=1e-5)


@pytest.mark.parametrize("wrap", ["repeat", "mirror", "clamp"])
@pytest.mark.parametrize("kind", ["bilinear", "nearest"])
def test_footprint_merges_a_pixels_samples_in_one_cell(kind: str, wrap: str) -> None:
    """Samples of a pixel that read one texel cell become one entry per corner
    (texel indices per run, not per sample), and painting still equals per-sample lookups,
    UVs past the edges (wrapped) and six owners (the gather, not the comparisons) included."""
    rng = np.random.default_rng(5)
    texels = rng.normal(size=(4, 5, 3))
    # 6 x 7 pixels of 8 samples, each pixel's UVs jittered inside one small patch
    centre = rng.uniform(-0.6, 1.6, (6, 7, 1, 2))
    sample_uv = centre + rng.uniform(-0.01, 0.01, (6, 7, 8, 2))
    sampling = TextureSampling(kind, wrap)
    for owners in (np.array([0]), np.arange(6)):
        sample_object = np.where(rng.random((6, 7, 8)) < 0.8, owners[-1], -1)
        factor = np.linspace(1.0, 2.0, len(owners))
        seen_by = footprint((4, 5), sampling, sample_uv, sample_object, owners)
        corners = 4 if kind == "bilinear" else 1
        hits = int(np.count_nonzero(sample_object >= 0))
        assert seen_by.pixel.size < hits * corners / 2  # merged: most pixels are one run
        per_sample = lookup(texels, sample_uv.reshape(-1, 2), sampling).reshape(6, 7, 8, 3)
        weight = np.where(sample_object >= 0, factor[-1], 0.0)
        expected = (per_sample * weight[..., None]).mean(axis=2)
        painted = seen_by.paint(texels.reshape(20, 3), factor)
        assert np.allclose(painted, expected, atol=1e-5)


@pytest.mark.parametrize("wrap", ["repeat", "mirror", "clamp"])
@pytest.mark.parametrize("size", [(6, 7), (1, 5), (4, 1)])
def test_footprint_entries_are_merged_on_the_texels_a_seam_included(
    wrap: str, size: tuple[int, int]
) -> None:
    """Runs found on the cell before wrapping are joined where their cells wrap onto the same
    texels (a seam under repeat, UVs past a clamped edge, a texture one texel wide): the
    entries and their float32 sums are exactly those of merging a pixel's consecutive samples
    on the texels they read (the plain rule, written out here per sample)."""
    rng = np.random.default_rng(9)
    spp = 8
    centre = rng.choice([0.0, 1.0, -1.0, 0.5], size=(5, 6, 1, 2))  # seams and edges
    sample_uv = (centre + rng.uniform(-0.02, 0.02, (5, 6, spp, 2))).astype(np.float32)
    sample_object = np.where(rng.random((5, 6, spp)) < 0.9, 0, -1)
    for kind in ("bilinear", "nearest"):
        sampling = TextureSampling(kind, wrap)
        seen_by = footprint(size, sampling, sample_uv, sample_object, np.array([0]))
        hits = np.flatnonzero(sample_object.reshape(-1) == 0)
        index, weight = texel_weights(sample_uv.reshape(-1, 2)[hits], size, sampling)
        key = np.column_stack([hits // spp, index])
        first = np.concatenate(([True], np.any(key[1:] != key[:-1], axis=1)))
        starts = np.flatnonzero(first)
        expected = np.add.reduceat(weight, starts, axis=0) / spp
        assert np.array_equal(seen_by.texel, index[starts].reshape(-1))
        assert np.array_equal(seen_by.pixel, np.repeat(hits[starts] // spp, index.shape[1]))
        assert seen_by.weight.dtype == expected.dtype
        assert np.array_equal(seen_by.weight, expected.reshape(-1))


def test_the_job_knows_texel_channels_and_refuses_their_keys_elsewhere(tmp_path: Path) -> None:
    from sensaov_cli.errors import SpecError
    from sensaov_cli.job.load import load_job

    def job(channel: str) -> Path:
        path = tmp_path / "job.yaml"
        path.write_text(
            f"version: 1\nscene: {SCENE}\nobjectives: [{{name: m, type: mean_luminance}}]\n"
            f"channels:\n  - {channel}\n"
        )
        return path

    spec = load_job(job("{name: t, kind: texel, pool: {kind: box, radius: 2}, units: uv_area}"))
    (channel,) = spec.channels
    assert (channel.pool.kind, channel.pool.radius, channel.units) == ("box", 2.0, "uv_area")
    for bad, where in [
        ("{name: t, kind: texel, pool: {kind: blur}}", "channels[0].pool.kind"),
        ("{name: t, kind: select, select: '*', pool: {kind: box}}", "channels[0]"),
        ("{name: t, kind: texel, units: pixels}", "channels[0].units"),
    ]:
        with pytest.raises(SpecError) as error:
            load_job(job(bad))
        assert where in str(error.value) + str(getattr(error.value, "where", ""))
