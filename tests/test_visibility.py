"""Coverage histograms and ranking on hand-made sample ids (no rendering)."""

from __future__ import annotations

from types import ModuleType

import numpy as np

from sensaov_cli.render.visibility import film_positions
from sensaov_cli.views.coverage import (
    BACKGROUND,
    Coverage,
    VisibilityPass,
    histogram,
    pixel_order,
    ranked,
)

B = BACKGROUND


def make_pass(samples: np.ndarray) -> VisibilityPass:
    height, width, spp = samples.shape
    coverage = histogram(samples.reshape(-1, spp))
    index, amount = ranked(coverage, (height, width), spp, ranks=2)
    uv = np.zeros((height, width, spp, 2), np.float32)
    return VisibilityPass(width, height, spp, ("a", "b", "c"), uv, coverage, index, amount)


SAMPLES = np.array(
    [
        [[0, 0, 0, 0], [1, 0, 1, B]],
        [[B, B, B, B], [2, 1, 0, 2]],
    ],
    np.int32,
)


def test_ranks_by_coverage_then_lowest_index() -> None:
    vis = make_pass(SAMPLES)
    assert vis.rank_index[0, 0].tolist() == [0, B]
    assert vis.rank_index[0, 1].tolist() == [1, 0]
    assert vis.rank_coverage[0, 1].tolist() == [0.5, 0.25]
    assert vis.rank_index[1, 0].tolist() == [B, B] and vis.rank_coverage[1, 0].sum() == 0
    assert vis.rank_index[1, 1].tolist() == [2, 0]  # 2 covers half; 0 and 1 tie, 0 first
    assert vis.coverage_hit.tolist() == [[1.0, 0.75], [0.0, 1.0]]


def test_paint_is_the_coverage_weighted_mean() -> None:
    vis = make_pass(SAMPLES)
    painted = vis.paint(np.array([1.0, 10.0, 100.0]))
    assert painted.tolist() == [[1.0, (10 + 1 + 10) / 4], [0.0, (100 + 10 + 1 + 100) / 4]]


def test_film_positions_are_stratified_inside_their_pixel(mi: ModuleType) -> None:
    points = film_positions(mi, 3, 2, 16, seed=1)
    positions = np.stack([np.array(points.x), np.array(points.y)], axis=-1).reshape(2, 3, 16, 2)
    pixel = np.floor(positions * np.array([3, 2])).astype(int)
    assert (pixel[..., 0] == np.arange(3)[None, :, None]).all()
    assert (pixel[..., 1] == np.arange(2)[:, None, None]).all()
    cell = np.floor((positions * np.array([3, 2]) % 1) * 4).astype(int)
    for y in range(2):
        for x in range(3):
            assert len({tuple(c) for c in cell[y, x]}) == 16  # one sample per 4x4 stratum


def test_regroup_merges_objects_into_their_groups() -> None:
    vis = make_pass(SAMPLES)
    grouped = vis.coverage.regroup(np.array([0, 0, 1], np.int32))  # a and b share group 0
    index, amount = ranked(grouped, (2, 2), 4, ranks=2)
    assert index[0, 1].tolist() == [0, B] and amount[0, 1].tolist() == [0.75, 0.0]
    assert index[1, 1].tolist() == [0, 1] and amount[1, 1].tolist() == [0.5, 0.5]


def test_coverage_orders_and_merges_as_the_plain_sorts_did() -> None:
    """Histogram, regroup and ranks use one stable sort of a combined key and run starts
    where they used lexsort, unique and searchsorted: on random sample ids (ties,
    background, 1 to 40 objects) the triplets and ranks are those of the plain versions, and
    a key too wide for 63 bits takes the lexsort."""
    rng = np.random.default_rng(3)

    def plain_regroup(cov: Coverage, group_of: np.ndarray) -> Coverage:
        groups = int(group_of.max()) + 1
        keys, inverse = np.unique(cov.pixel * groups + group_of[cov.obj], return_inverse=True)
        counts = np.bincount(inverse, weights=cov.count).astype(np.int32)
        pixel, group = keys // groups, (keys % groups).astype(np.int32)
        order = np.lexsort((group, -counts, pixel))
        return Coverage(pixel[order], group[order], counts[order])

    for objects in (1, 3, 40):
        samples = rng.integers(-1, objects, size=(500, 16)).astype(np.int32)
        cov = histogram(samples)
        flat = np.sort(samples, axis=1)
        for row in (0, 7, 499):  # every (pixel, object) count, most covered first
            ids, counts = np.unique(flat[row][flat[row] >= 0], return_counts=True)
            expected = sorted(zip(-counts, ids, strict=True))
            at = cov.pixel == row
            assert list(zip(-cov.count[at], cov.obj[at], strict=True)) == expected
        group_of = rng.integers(0, max(1, objects // 2), size=objects).astype(np.int32)
        ours, plain = cov.regroup(group_of), plain_regroup(cov, group_of)
        for name in ("pixel", "obj", "count"):
            assert np.array_equal(getattr(ours, name), getattr(plain, name))
        index, amount = ranked(cov, (20, 25), 16, ranks=6)
        first = np.searchsorted(cov.pixel, cov.pixel, side="left")
        rank = np.arange(len(cov.pixel)) - first
        keep = rank < 6
        assert np.array_equal(index.reshape(-1, 6)[cov.pixel[keep], rank[keep]], cov.obj[keep])
    wide = np.array([2**40, 5, 2**40]), np.array([1, 3, 2]), np.array([7, 2**30, 9])
    assert pixel_order(*wide).tolist() == np.lexsort((wide[2], -wide[1], wide[0])).tolist()


def test_traced_uvs_lie_on_hit_surfaces(mi: ModuleType, job_writer) -> None:  # noqa: ANN001
    from sensaov_cli.job.load import load_job
    from sensaov_cli.render.loading import load_job_scene
    from sensaov_cli.render.visibility import trace

    loaded = load_job_scene(load_job(job_writer("uv")))
    vis = trace(mi, loaded.scene, loaded.sensor, loaded.objects, 4, with_uv=True)
    assert vis.sample_uv is not None and vis.sample_uv.shape == (24, 24, 4, 2)
    covered = vis.coverage_hit == 1.0
    uv = vis.sample_uv[covered]
    assert np.all((uv >= 0) & (uv <= 1)) and uv.std() > 0.1  # real surface coordinates
    # A sample on a shape the buffer does not list is background too, UV 0 (zeroed in the
    # kernel): trace as if the buffer lacked the most covered object.
    most = int(np.bincount(vis.sample_object[vis.sample_object >= 0]).argmax())
    fewer = tuple(name if i != most else "not-in-the-scene" for i, name in enumerate(vis.objects))
    partial = trace(mi, loaded.scene, loaded.sensor, fewer, 4, with_uv=True)
    assert partial.sample_uv is not None and partial.sample_object is not None
    unlisted = (partial.sample_object == BACKGROUND) & (vis.sample_object == most)
    assert unlisted.any() and not np.any(partial.sample_uv[unlisted])
    assert trace(mi, loaded.scene, loaded.sensor, loaded.objects, 4).sample_uv is None
