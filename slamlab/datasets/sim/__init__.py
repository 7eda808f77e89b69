"""slamlab's simulator: a walking THOR-OP humanoid in a seeded indoor world, written as
THOR-format files (lidar, joints, Kinect v2 RGB-D) with ground truth beside them.

`load_sim(seed=0, ...)` is the default dataset (conf/dataset/sim.yaml); `slamlab-sim OUT`
writes a sequence into a folder.
"""

from slamlab.datasets.sim.generate import SIM_VERSION, SimParams, generate_atomic, generate_sequence, load_sim, read_sim_folder, sim_folder

__all__ = ["SIM_VERSION", "SimParams", "generate_atomic", "generate_sequence", "load_sim", "read_sim_folder", "sim_folder"]
