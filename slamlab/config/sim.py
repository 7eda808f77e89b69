"""The simulator's knobs (`SimParams`) and the `dataset=sim` schema built from them.

`SimParams` is the single source of the simulator's keys, defaults and types: the schema
`dataset/sim` adds only what the loader takes besides them (`_target_`, where the cache
lives, the calibration folder), so `conf/dataset/sim.yaml` no longer repeats ~30 defaults.
The simulator (`slamlab.datasets.sim`) re-exports `SimParams` and checks its ranges
(`validate_params`).
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from typing import Optional


@dataclass(frozen=True)
class SimParams:
    """Every knob of the simulator (units in the names). Same params = same files, byte for
    byte. `seed` is the dataset seed, independent of the SLAM filter's seed."""

    seed: int = 0
    layout: str = "ring"  # "ring" (17 x 13.5 m, one corridor loop) | "loops" (40 x 30 m, figure-eight, 176 m; see world.py)
    duration_s: float = 85.0  # total, including the static start; one lap takes ~78 s
    stand_s: float = 2.5  # robot stands still at the start
    walk_speed_mps: float = 0.45
    turn_rate_dps: float = 35.0  # turns in place at the corners
    n_clutter: int = 22  # boxes and pillars (about half lower than the lidar)
    world_scale: float = 1.0  # building size vs the 17 x 13.5 m plan (a lap takes ~78 s x scale)
    n_people: int = 0  # people walking in the corridor (moving cylinders), off by default
    step_freq_hz: float = 1.6  # gait: body pitch at this, roll at half of it
    roll_amp_deg: float = 2.5
    pitch_amp_deg: float = 1.5
    jerk_deg: float = 0.0  # occasional larger roll/pitch jerks up to this (0 = none)
    jerk_every_s: float = 8.0  # mean time between jerks
    neck_sweep_deg: float = 0.0  # neck yaw sweeps +- this (0 = only the occasional glances)
    neck_sweep_period_s: float = 12.0
    range_noise_m: float = 0.01
    dropout_fraction: float = 0.005
    odom_scale_bias: float = 0.025  # odometry over-counts distance by 2.5 %
    odom_yaw_drift_deg_per_min: float = 2.0  # heading drift while stepping
    odom_yaw_bias_deg_per_m: float = 0.0
    odom_noise_m_per_sqrt_s: float = 0.005
    odom_noise_deg_per_sqrt_s: float = 0.3
    imu_noise_deg: float = 0.2
    rgbd: bool = True  # write DEPTH_0.mat (+ RGB if `rgb`)
    rgb: bool = True
    kinect_rate_hz: float = 2.0
    kinect_scale: float = 0.25  # 1.0 = 512x424 depth, 1920x1080 colour
    depth_noise_mm: float = 2.0
    label_every: int = 5  # ground labels for every k-th depth frame
    texture_res_m: float = 0.02
    occupancy_res_m: float = 0.05



def _sim_dataset_schema() -> type:
    """`dataset=sim`: every SimParams field (same default and type), after `_target_`, and the
    loader's own options."""
    hints = typing.get_type_hints(SimParams)
    knobs = [(f.name, hints[f.name], dataclasses.field(default=f.default)) for f in dataclasses.fields(SimParams)]
    return dataclasses.make_dataclass(
        "SimDatasetConfig",
        [
            ("_target_", str, dataclasses.field(default="slamlab.datasets.sim.load_sim")),
            *knobs,
            # a real cameraParam/ folder to take the Kinect numbers from; null = built-in THOR values
            ("calibration_dir", Optional[str], dataclasses.field(default=None)),
            ("cache_dir", Optional[str], dataclasses.field(default=None)),  # null = $SLAMLAB_CACHE_DIR/sim or ~/.cache/slamlab/sim
            ("regenerate", bool, dataclasses.field(default=False)),  # rebuild even if cached
        ],
        namespace={"__doc__": "`dataset=sim`: the built-in simulated THOR-OP sequence (see SimParams)."},
    )


SimDatasetConfig = _sim_dataset_schema()
SimDatasetConfig.__module__ = __name__  # pickled by name (sweep launchers send configs to other processes)
