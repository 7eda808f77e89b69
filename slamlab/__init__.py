"""slamlab: configurable particle-filter SLAM with texture mapping."""

__version__ = "0.1.0"
