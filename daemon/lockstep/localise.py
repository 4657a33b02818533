# `arbiterd simulate --localise N`: random starts on a world's map with no pose given, judged.
from __future__ import annotations

import math
import random
import statistics
import time
from typing import Any

import numpy as np

from daemon.config import load_config
from sim.mapping_truth import reachable_free_cells, truth_occupancy, world_grid
from sim.raycast import ray_angles
from sim.settings import SimConfig, SimSettings
from sim.stepper import SimWorld
from sim.world import Pose
from slam.grid import OccupancyGrid
from slam.mapper import Mapper, MapperConfig
from slam.pose import Pose2, between, compose

#: a pose within this of the truth is found; a confident pose farther off is wrong (m, rad)
FOUND_M, FOUND_RAD = 0.10, math.radians(5)
#: revolutions a trial may take before it counts as not sure (ambiguous or not found)
REVOLUTIONS = 300
#: between revolutions the robot drives on this far, or turns this much where it has no room
#: ahead (m, rad: 0.4 m/s and 2.5 rad/s at 10 revolutions a second), with exact odometry
STEP_M, TURN_RAD = 0.04, 0.25
#: room kept ahead of the footprint when driving on (m)
AHEAD_M = 0.35
#: the built-in worlds a run covers without --world
WORLDS = ("apartment", "warehouse", "loop")
RESOLUTION = 0.05


def world_map(sim: SimWorld, resolution: float = RESOLUTION) -> OccupancyGrid:
    """The saved map a robot would have of the world: its walls occupied, the space reachable
    from its start free, the rest unknown."""
    world = sim.world
    spec = world_grid(world, resolution, margin=0.5)
    walls = truth_occupancy(world, resolution, spec.origin_x, spec.origin_y, spec.width,
                            spec.height)
    inside = reachable_free_cells(world, resolution, 0.0, grid=spec)
    occupancy = np.full(spec.shape, -1, dtype=np.int8)
    occupancy[inside] = 0
    occupancy[walls] = 100
    return OccupancyGrid.from_occupancy(occupancy, resolution, spec.origin_x, spec.origin_y)


def random_starts(sim: SimWorld, count: int, seed: int) -> list[Pose2]:
    """``count`` poses where the robot fits, reachable from the world's start, any heading."""
    world = sim.world
    spec = world_grid(world, 0.1)
    room = reachable_free_cells(world, 0.1, sim.config.footprint_radius + 0.05, grid=spec)
    rows, cols = np.nonzero(room)
    rng = random.Random(seed)
    starts = []
    for _ in range(count):
        i = rng.randrange(len(rows))
        starts.append((spec.origin_x + (cols[i] + 0.5) * 0.1,
                       spec.origin_y + (rows[i] + 0.5) * 0.1, rng.uniform(-math.pi, math.pi)))
    return starts


def scan_points(sim: SimWorld, angles: np.ndarray) -> np.ndarray:
    """One revolution (noise as configured) as points in the robot frame."""
    ranges = sim.scan()
    ok = np.isfinite(ranges)
    return np.column_stack([ranges[ok] * np.cos(angles[ok]), ranges[ok] * np.sin(angles[ok])])


def localise_world(world: str, count: int, seed: int,
                   kidnap: bool = False) -> list[dict[str, Any]]:
    """``count`` trials on one world: teleport, forget the pose, let the mapper find it
    (``kidnap``: teleport without telling the mapper, once it is sure of the first pose)."""
    config = load_config(None, sim=True, env={})
    config.update("sim", {"seed": seed, "world_file": world})
    sim_config = SimConfig.from_settings(config.get(SimSettings))
    sim = SimWorld(sim_config)
    mapper = Mapper(MapperConfig(mode="localize", resolution=RESOLUTION), grid=world_map(sim))
    angles = ray_angles(sim_config.lidar_rays)
    period = 1.0 / sim_config.lidar_rate
    rows = []
    starts = random_starts(sim, count + 1 if kidnap else count, seed)
    odometry: list[Pose2] = [(0.0, 0.0, 0.0)]  # the wheels' pose: a teleport does not move it
    if kidnap:
        sim.reset(Pose(*starts[0]))
        mapper.find_pose()
        _trial(world, -1, starts.pop(0), mapper, sim, angles, period, odometry)
    for n, start in enumerate(starts):
        sim.reset(Pose(*start))
        if kidnap:
            rows.append(_kidnapped(world, n, start, mapper, sim, angles, period, odometry))
        else:
            mapper.find_pose()
            rows.append(_trial(world, n, start, mapper, sim, angles, period, odometry))
    return rows


def _kidnapped(world: str, n: int, truth: Pose2, mapper: Mapper, sim: SimWorld,
               angles: np.ndarray, period: float, odometry: list[Pose2]) -> dict[str, Any]:
    """Revolutions after an untold teleport: when the mapper noticed (its status left
    tracking) and when it was sure again, and where."""
    start, odom0 = truth, odometry[0]
    row: dict[str, Any] = {"world": world, "trial": n, "truth": [round(v, 3) for v in truth],
                           "kidnap": True}
    noticed: int | None = None
    for revolution in range(1, REVOLUTIONS + 1):
        if revolution > 1:
            truth = _drive_on(sim, truth)
        odometry[0] = compose(odom0, between(start, truth))
        result = mapper.add_scan(odometry[0], scan_points(sim, angles), revolution * period)
        if result.status != "tracking" and noticed is None:
            noticed = revolution
            row["noticed_s"] = round(revolution * period, 2)
        if result.status == "tracking" and noticed is not None:
            error = math.hypot(result.pose[0] - truth[0], result.pose[1] - truth[1])
            turn = abs(math.remainder(result.pose[2] - truth[2], math.tau))
            good = error <= FOUND_M and turn <= FOUND_RAD
            row.update(seconds=round(revolution * period, 2), error_m=round(error, 3),
                       outcome="found" if good else "wrong")
            return row
    pose = mapper.trajectory[-1][1]
    error = math.hypot(pose[0] - truth[0], pose[1] - truth[1])
    turn = abs(math.remainder(pose[2] - truth[2], math.tau))
    lost = mapper.health()["lost"]
    row.update(seconds=round(REVOLUTIONS * period, 2), error_m=round(error, 3),
               outcome="ambiguous" if lost else
               "found" if error <= FOUND_M and turn <= FOUND_RAD else "wrong")
    return row


def _trial(world: str, n: int, truth: Pose2, mapper: Mapper, sim: SimWorld,
           angles: np.ndarray, period: float, odometry: list[Pose2]) -> dict[str, Any]:
    compute = 0.0
    start, odom0 = truth, odometry[0]
    row: dict[str, Any] = {"world": world, "trial": n, "truth": [round(v, 3) for v in truth]}
    for revolution in range(1, REVOLUTIONS + 1):
        if revolution > 1:
            truth = _drive_on(sim, truth)
        points = scan_points(sim, angles)
        began = time.perf_counter()
        odometry[0] = compose(odom0, between(start, truth))
        result = mapper.add_scan(odometry[0], points, revolution * period)
        compute += time.perf_counter() - began
        row.update(revolutions=revolution, compute_s=round(compute, 3),
                   seconds=round(compute + revolution * period, 3), status=result.status,
                   candidates=len(result.candidates))
        if result.status == "tracking":
            error = math.hypot(result.pose[0] - truth[0], result.pose[1] - truth[1])
            turn = abs(math.remainder(result.pose[2] - truth[2], math.tau))
            row.update(pose=[round(v, 3) for v in result.pose], error_m=round(error, 3),
                       error_deg=round(math.degrees(turn), 2),
                       outcome="found" if error <= FOUND_M and turn <= FOUND_RAD else "wrong")
            return row
    row["outcome"] = "ambiguous" if row["status"] == "ambiguous" else "not_found"
    return row


def _drive_on(sim: SimWorld, pose: Pose2) -> Pose2:
    """The next pose of a robot that drives straight on while it has room, else turns."""
    ahead = compose(pose, (STEP_M + AHEAD_M, 0.0, 0.0))
    room = sim.config.footprint_radius + 0.05
    if sim.world.clearance(ahead[0], ahead[1]) > room:
        pose = compose(pose, (STEP_M, 0.0, 0.0))
    else:
        pose = compose(pose, (0.0, 0.0, TURN_RAD))
    sim.reset(Pose(*pose))
    return pose


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    outcomes = [r["outcome"] for r in rows]
    sure = [r["seconds"] for r in rows if r["outcome"] in ("found", "wrong")]
    trials = len(rows)
    out: dict[str, Any] = {"trials": trials}
    for key in ("found", "ambiguous", "wrong", "not_found"):
        out[key] = outcomes.count(key)
    for key in ("found", "ambiguous", "wrong"):
        out[f"{key}_share"] = round(out[key] / trials, 4) if trials else 0.0
    out["median_s"] = round(statistics.median(sure), 3) if sure else None
    out["max_s"] = round(max(sure), 3) if sure else None
    noticed = [r["noticed_s"] for r in rows if "noticed_s" in r]
    if any(r.get("kidnap") for r in rows):
        out["noticed"] = len(noticed)
        out["median_notice_s"] = round(statistics.median(noticed), 3) if noticed else None
    return out
