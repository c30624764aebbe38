"""The training entry point (the loop, data and run files live in insertnerf_cli/training/)."""
from .training import TrainConfig, TrainResult, train

__all__ = ["TrainConfig", "TrainResult", "train"]
