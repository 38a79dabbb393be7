"""``bench.world_sizes``: the table and figure by world size from ``bench.world``'s results
(made up here: nothing is timed or traced)."""

from __future__ import annotations

import json

import pytest

from bench import world_sizes


@pytest.fixture(scope="module", autouse=True)
def warm_engine():
    """No engine kernel is used: override the session's warm-up (tests/conftest.py)."""
    return None


def run(triangles: int, embree_ms: float, changes_ms: float) -> dict:
    """A ``bench.world`` result of one lidar count with three frames of Embree and with_changes."""
    frames = {
        "embree": [{"commit": 0.1, "trace": embree_ms - 0.1, "static": 900.0}] * 3,
        "dacrt changes": [{"scene": 3.0, "trace": changes_ms - 3.0}] * 3,
    }
    return {
        "args": {"actors": 40, "threads": 2},
        "machine": {"cpu": "test CPU"},
        "load": [0.5, 1.5],
        "world": {"triangles": triangles},
        "counts": {"1": {"frames": frames, "checks": [], "service_identical": True}},
    }


def test_sizes_come_back_smallest_first_with_embree_over_each_engine(tmp_path):
    for triangles, embree, changes in [(4_000_000, 25.0, 100.0), (500_000, 10.0, 40.0)]:
        (tmp_path / str(triangles)).mkdir()
        (tmp_path / str(triangles) / "world.json").write_text(
            json.dumps(run(triangles, embree, changes))
        )
    table = world_sizes.write(tmp_path)
    rows = [line for line in table.splitlines() if line.startswith("| 5") or "4,000,000" in line]
    assert rows[0].startswith("| 500,000 | 1 | 10.0 | 40.0: **0.25×**")
    assert rows[1].startswith("| 4,000,000 | 1 | 25.0 | 100.0: **0.25×**")
    assert "service rig" not in table  # an engine no run has is left out
    assert (tmp_path / "world-sizes.md").read_text() == table + "\n"
    assert (tmp_path / "world-sizes.png").stat().st_size > 10_000


def test_a_folder_without_results_is_named(tmp_path):
    with pytest.raises(SystemExit, match="no bench.world results"):
        world_sizes.write(tmp_path)
