"""Texture mapping: colour the floor of the occupancy map from the Kinect RGB-D frames.

Modules (one step each, in pipeline order):
- `backproject`: depth (m, already un-mirrored by the reader) -> IR-frame points, optional
  lens undistortion through a per-pixel ray table;
- `ground`: floor detectors chosen by `conf/ground/*.yaml` (`threshold`, `plane`, `image_plane`);
- `align`: IR frame -> RGB frame (R, T mm) -> RGB pixel -> colour;
- `texture_map`: the colour grid aligned with the occupancy grid (mean or robust average);
- `detection`: detector-vs-label pixel counts (`DetectionCounts`);
- `pipeline`: `run_texture(sequence, times, poses, grid, ground_cfg, texture_cfg, progress)`
  -> `TextureResult`, `save_texture_outputs` (scored by `slamlab.eval.texture.texture_metrics`);
  `run_textures(...)` does several trajectories in one pass over the RGB-D stream.
Test frames are rendered by the simulator's Kinect (`tests/synthetic_rgbd.py`).
"""
