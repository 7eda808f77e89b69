"""Map a trajectory: the occupancy grid that a sequence's scans draw when each is placed at
a given pose.

Any filter's final map is this function of some poses: the course filter's shared map is
its online poses at the processed steps; a pose graph's map is its optimised poses; a map
made on purpose from a trajectory with an error injected (a rotation from some time on)
shows what a broken loop looks like. It uses the filters' own pieces (`scan_to_points`'s
projection, `OccupancyGrid.insert`'s ray casting), so on the course filter it gives the
run's map to the bit (tested).
"""

from __future__ import annotations

import numpy as np

from slamlab.frames import GridImage, Sequence
from slamlab.geometry import FloatArray
from slamlab.slam.grid import MapSettings, OccupancyGrid
from slamlab.slam.scan import points_to_world, range_limits, scans_to_points

CHUNK = 500  # scans projected at once (a few MB of points)


def map_from_trajectory(
    sequence: Sequence,
    poses: FloatArray,
    settings: MapSettings,
    scan_indices: np.ndarray | None = None,
) -> GridImage:
    """The log-odds map of the scans `scan_indices` (positions in `sequence.scans`, in the
    order they are inserted; default: every scan that has a pose) placed at `poses` (N, 3)
    (x m, y m, theta rad; pose i is scan i's). The grid starts centred on the first inserted
    scan's pose and grows as `OccupancyGrid` does. Returns float32 log-odds as a GridImage."""
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must be (N, 3), got {poses.shape}")
    if len(poses) > len(sequence.scans):
        raise ValueError(f"{len(poses)} poses for a sequence of {len(sequence.scans)} scans")
    order = np.arange(len(poses)) if scan_indices is None else np.asarray(scan_indices, dtype=np.int64)
    if len(order) == 0:
        raise ValueError("no scans to map")
    if order.min() < 0 or order.max() >= len(poses):
        raise ValueError(f"scan_indices must lie in 0..{len(poses) - 1}")
    min_r, max_r = range_limits(settings, sequence)
    start = poses[order[0]]
    grid = OccupancyGrid(settings, (float(start[0]), float(start[1])))
    scans = sequence.scans
    for lo in range(0, len(order), CHUNK):
        chunk = order[lo : lo + CHUNK]
        # each scan's points as the filters project them (`scans_to_points`: to the bit)
        points = scans_to_points([scans[int(i)] for i in chunk], sequence.body_height_m, min_r, max_r, settings.ground_threshold_m)
        for i, pts in zip(chunk, points):
            if len(pts.xy) == 0:
                continue
            pose = poses[i]
            grid.insert(points_to_world(pts.origin.reshape(1, 2), pose)[0], points_to_world(pts.xy, pose))
    return grid.take_image()
