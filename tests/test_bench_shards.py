"""Bench figure 10 merges shards it writes itself: they must stay shards merge accepts.

The rules merge checks a shard's provenance by (buffer/shards.py) grew after the
figure was written, and a full ``make bench`` failed on figure 10 after 14 minutes; this
runs the figure's merge at the quick settings in a fraction of a second.
"""

from __future__ import annotations

from pathlib import Path

from bench.fig_farm import _merge
from bench.jobs import Workspace
from bench.settings import quick


def test_figure_10s_synthetic_shards_merge(tmp_path: Path) -> None:
    row = _merge(Workspace(tmp_path, "llvm_ad_rgb"), quick("llvm_ad_rgb"))
    assert row.case.startswith("merge 4 shards") and min(row.stats.values) > 0
    assert (tmp_path / "merge" / "buffer.npz").is_file()
