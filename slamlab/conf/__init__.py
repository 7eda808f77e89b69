"""Hydra config root (shipped in the wheel; `conf/` at the top of the checkout links here)."""
