"""``bench.order`` (storage order side by side) on a small procedural mesh: every mode builds,
traces and passes the script's own checks of its answers. Nothing here is timed."""

from __future__ import annotations

import numpy as np
import sample_scenes

from bench import order


def test_every_mode_traces_and_agrees():
    (vertices, faces), *_ = sample_scenes.multi(3)
    origins, directions = sample_scenes.mixed_rays([(vertices, faces)], 3, n=2000)
    rows = order.compare(
        "grid", vertices, faces, {2000: (origins, directions)}, 1, 1, 0, list(order.MODES), None
    )
    (row,) = rows
    assert set(row["ms"]) == set(order.MODES) and row["hits"] > 0
    assert "| grid |" in order.table(rows)
    assert np.isfinite(list(row["pack_ms"].values())).all()
