"""hydra-ray-launcher's RayLauncher, fixed for joining a running Ray cluster.

The plugin (1.2.2) always adds `object_store_memory` to `ray.init(...)`, and Ray refuses
that option (and `include_dashboard`, `num_cpus`) when `address` names an existing cluster:
"When connecting to an existing cluster, object_store_memory must not be provided". With an
address set, these start-a-cluster options are set to None here, which Ray reads as "not
given" and the plugin leaves alone. Everything else is the plugin's.

It lives in the `hydra_plugins` namespace because Hydra only accepts launchers from there;
without hydra-ray-launcher installed (`pip install 'slamlab[ray]'`) it defines nothing.
"""

from __future__ import annotations

from collections.abc import Sequence

from hydra.core.utils import JobReturn
from omegaconf import open_dict

try:
    from hydra_plugins.hydra_ray_launcher.ray_launcher import RayLauncher
except ImportError:  # the [ray] extra is not installed: hydra/launcher=ray is then unavailable
    RayLauncher = None

# ray.init options that only make sense when Ray starts a cluster on this machine
LOCAL_ONLY = ("object_store_memory", "include_dashboard", "num_cpus", "num_gpus")

if RayLauncher is not None:

    class SlamlabRayLauncher(RayLauncher):
        """The Ray launcher; `hydra.launcher.ray.init.address` may name a running cluster."""

        def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
            init = self.ray_cfg.init
            if init.get("address"):
                with open_dict(init):
                    for key in LOCAL_ONLY:
                        init[key] = None
            return super().launch(job_overrides, initial_job_idx)
