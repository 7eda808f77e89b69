"""Schemas of the texture stage: `ground/` (the floor detector) and `texture/`.

As in `slamlab.config.slam`: one dataclass per choice holds the keys, defaults, types and
range checks; the YAML files pick one and override values. The texture stage receives a
`TextureConfig` object and built detectors, never a Hydra config.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, List, Optional

from slamlab.config.checks import require_bool, require_int, require_nonnegative, require_positive
from slamlab.errors import ConfigError
from slamlab.frames import KINECT_MAX_DEPTH_M, KINECT_MIN_DEPTH_M


# ---- ground/ -------------------------------------------------------------------------------
@dataclass
class ThresholdGroundConfig:
    """`ground=threshold`: floor = depth points whose world height |z| is below a tolerance
    (z = 0 on the floor). Cheapest detector; trusts the pose chain (body height, roll/pitch,
    head angles)."""

    GROUP: ClassVar[str] = "ground"
    _target_: str = "slamlab.texture.ground.ThresholdGround"
    name: str = "threshold"
    tolerance_m: float = 0.05  # |height| below this (m) is floor

    def __post_init__(self) -> None:
        require_positive(self.GROUP, "tolerance_m", self.tolerance_m)


@dataclass
class PlaneGroundConfig:
    """`ground=plane`: floor = inliers of a seeded RANSAC plane fit (NumPy, reproducible) on the
    frame's world points, accepted when the plane is near horizontal and near z = 0. Up to
    `max_planes` planes are tried so a dominant wall does not hide the floor."""

    GROUP: ClassVar[str] = "ground"
    _target_: str = "slamlab.texture.ground.PlaneGround"
    name: str = "plane"
    distance_threshold_m: float = 0.03  # inlier distance to the plane (m)
    ransac_n: int = 3  # points per RANSAC hypothesis
    num_iterations: int = 200  # RANSAC iterations per plane
    max_tilt_deg: float = 10.0  # plane normal within this of vertical
    max_height_m: float = 0.15  # plane height under the camera within this of z = 0 (m)
    fit_max_points: int = 5000  # RANSAC on a random subsample of this many points (speed)
    max_planes: int = 3  # planes tried per frame before giving up
    min_inliers: int = 200  # smaller planes are not trusted
    refine_iterations: int = 2  # least-squares refits on all inliers (accuracy, run-to-run stability)
    seed: int = 0  # RANSAC seed: the same seed and frames give the same floor, bit for bit

    def __post_init__(self) -> None:
        g = self.GROUP
        require_positive(g, "distance_threshold_m", self.distance_threshold_m)
        require_int(g, "ransac_n", self.ransac_n, 3)
        require_int(g, "num_iterations", self.num_iterations, 1)
        require_nonnegative(g, "max_tilt_deg", self.max_tilt_deg)
        require_nonnegative(g, "max_height_m", self.max_height_m)
        require_int(g, "fit_max_points", self.fit_max_points, 3)
        require_int(g, "max_planes", self.max_planes, 1)
        require_int(g, "min_inliers", self.min_inliers, 0)
        require_int(g, "refine_iterations", self.refine_iterations, 0)
        require_int(g, "seed", self.seed, 0)


@dataclass
class ImagePlaneGroundConfig:
    """`ground=image_plane`: floor = pixels satisfying the slides' plane test in image /
    inverse-depth coordinates, |a0' u + a1' v + a2' + a3' d| < eps, with the plane
    coefficients from the head's pose. The left side is (height of the point) / depth, so the
    height tolerance is eps x depth."""

    GROUP: ClassVar[str] = "ground"
    _target_: str = "slamlab.texture.ground.ImagePlaneGround"
    name: str = "image_plane"
    eps: float = 0.02  # dimensionless: 2 cm at 1 m, 6 cm at 3 m

    def __post_init__(self) -> None:
        require_positive(self.GROUP, "eps", self.eps)


# ---- texture/ ------------------------------------------------------------------------------
AVERAGES = ("mean", "robust")


@dataclass
class TextureConfig:
    """`texture=default`: colour the floor cells of the occupancy grid from the Kinect RGB-D
    frames (`texture=none` is this with `enabled: false`)."""

    GROUP: ClassVar[str] = "texture"
    enabled: bool = True
    stride: int = 1  # every k-th depth pixel in u and v (1 = all 512x424, ~20 ms/frame with `threshold`;
    # 2 = 256x212, ~3x faster, still several points per 5 cm cell at 3 m on a full-resolution Kinect)
    frame_every: int = 1  # use every k-th RGB-D frame
    max_frames: Optional[int] = None  # stop after this many used frames (null = all)
    min_depth_m: float = KINECT_MIN_DEPTH_M  # valid depth range (m), the Kinect v2's by default
    max_depth_m: float = KINECT_MAX_DEPTH_M
    undistort_depth: bool = True  # correct the IR lens distortion (kc); precomputed per pixel, free per frame
    distort_rgb: bool = True  # apply the RGB lens distortion (kc) when projecting into the colour image
    calibration_mirrored: bool = False  # true if the calibration was estimated on the mirrored (as stored) images
    max_rgb_dt_s: float = 0.1  # skip frames whose colour image is further than this from the depth time (s)
    max_pose_gap_s: float = 0.5  # skip frames further than this outside the trajectory's time span (s)
    average: str = "mean"  # mean | robust (gated mean: ignore colours far from the cell's mean)
    robust_reject: float = 60.0  # robust: max per-channel difference (0-255) from the cell mean
    robust_min_count: int = 5  # robust: gate only cells with at least this many points
    # on labelled (simulated) frames, also measure these ground/ detectors' precision/recall
    evaluate_detectors: List[str] = field(default_factory=lambda: ["threshold", "plane", "image_plane"])

    def __post_init__(self) -> None:
        g = self.GROUP
        require_bool(g, "enabled", self.enabled)
        require_int(g, "stride", self.stride, 1)
        require_int(g, "frame_every", self.frame_every, 1)
        require_int(g, "max_frames", self.max_frames, 0, allow_none=True)
        require_nonnegative(g, "min_depth_m", self.min_depth_m)
        require_positive(g, "max_depth_m", self.max_depth_m)
        if self.min_depth_m >= self.max_depth_m:
            raise ConfigError(f"{g}.max_depth_m", f"must be greater than texture.min_depth_m ({self.min_depth_m})")
        require_nonnegative(g, "max_rgb_dt_s", self.max_rgb_dt_s)
        require_nonnegative(g, "max_pose_gap_s", self.max_pose_gap_s)
        if self.average not in AVERAGES:
            raise ConfigError(f"{g}.average", f"must be 'mean' or 'robust', got {self.average!r}")
        require_nonnegative(g, "robust_reject", self.robust_reject)
        require_int(g, "robust_min_count", self.robust_min_count, 0)
        self.evaluate_detectors = [str(n) for n in self.evaluate_detectors or []]


__all__ = ["ThresholdGroundConfig", "PlaneGroundConfig", "ImagePlaneGroundConfig", "TextureConfig"]
