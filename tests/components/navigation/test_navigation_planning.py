# Navigation's planning process: the same plans and frontiers as inline, in costmap cells the
# daemon sees as the worker writes them, and no process or shared memory left after close.
from __future__ import annotations

import math
import multiprocessing
from multiprocessing.shared_memory import SharedMemory

import numpy as np
import pytest

from daemon.components.navigation.planning import (
    PlanningWorker,
    Scans,
    fold_and_look,
    fold_and_plan,
)
from nav.costmap import Costmap, CostParams, centred_area

AREA = centred_area(0.1, 12.0)
PARAMS = CostParams(radius_m=0.25)


def room_scans() -> Scans:
    """Two revolutions inside a 6 x 4 m room with a wall stub, seen from two poses."""
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    scans: Scans = []
    for pose in ((0.0, 0.0, 0.0), (1.0, 0.5, 0.3)):
        px, py, theta = pose
        dx, dy = np.cos(angles + theta), np.sin(angles + theta)
        with np.errstate(divide="ignore"):
            tx = np.where(dx > 0, (3.0 - px) / dx, (-3.0 - px) / dx)
            ty = np.where(dy > 0, (2.0 - py) / dy, (-2.0 - py) / dy)
        r = np.minimum(np.abs(tx), np.abs(ty))
        scans.append((pose, r * np.cos(angles), r * np.sin(angles)))
    return scans


async def test_the_worker_plans_and_looks_as_inline_and_shares_its_cells() -> None:
    (pose, xs, ys), second = room_scans()
    part: Scans = [(pose, xs[:120], ys[:120])]  # a third of a revolution: frontiers remain
    inline = Costmap(AREA, PARAMS)
    expected_look = fold_and_look(inline, part, (0.0, 0.0, 0.0), 10, 2)
    expected_plan = fold_and_plan(inline, [second], (0.0, 0.0, 0.0), (2.0, 1.0, 0.0), 2)
    worker = PlanningWorker(AREA, PARAMS)
    name = worker.cells.memory.name
    try:
        assert not worker.costmap.seen.any()
        looked = await worker.look(part, (0.0, 0.0, 0.0), 10, 2)
        planned = await worker.plan([second], (0.0, 0.0, 0.0), (2.0, 1.0, 0.0), 2)
        # the daemon's view of the cells is what the worker folded in
        assert np.array_equal(worker.costmap.seen, inline.seen)
        assert np.array_equal(worker.costmap.evidence, inline.evidence)
    finally:
        worker.close()
    assert planned.plan.found and np.array_equal(planned.plan.points, expected_plan.plan.points)
    assert np.array_equal(planned.costs, expected_plan.costs) and planned.ms >= 0
    assert looked.explored_m2 == pytest.approx(expected_look.explored_m2)
    assert looked.frontiers and [(f.x, f.y, f.size_m) for f in looked.frontiers] == \
        [(f.x, f.y, f.size_m) for f in expected_look.frontiers]
    # the planner's worker is gone (other tests of this process may leave their own children)
    assert not [child for child in multiprocessing.active_children()
                if not child.name.startswith("arbiterd-camera")]
    with pytest.raises(FileNotFoundError):
        SharedMemory(name=name)


async def test_a_failing_job_raises_in_the_daemon_and_the_worker_goes_on() -> None:
    worker = PlanningWorker(AREA, PARAMS)
    try:
        with pytest.raises(ValueError):
            await worker.plan([((0.0, 0.0, 0.0), np.ones(3), np.ones(2))], (0.0, 0.0, 0.0),
                              (1.0, 0.0, 0.0), 2)
        planned = await worker.plan([], (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 2)
        assert planned.plan.found
    finally:
        worker.close()
