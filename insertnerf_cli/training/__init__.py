"""Training the generator: ``train(dataset_dir, run_dir, TrainConfig, device) -> TrainResult``."""
from .config import TrainConfig
from .loop import TrainResult, train, validate

__all__ = ["TrainConfig", "TrainResult", "train", "validate"]
