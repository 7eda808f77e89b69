"""Hydra config root (shipped in the wheel; `conf/` at the top of the checkout links here).

Importing it registers the schemas the YAML files extend (`slamlab.config.store`)."""

import slamlab.config.store  # noqa: F401  (registers schema/<group>/<choice> in the ConfigStore)
