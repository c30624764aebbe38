"""Training the generator: ``train(dataset_dir, run_dir, TrainConfig, device) -> TrainResult``."""
from insertnerf_cli.training.config import TrainConfig
from insertnerf_cli.training.loop import TrainResult, train, validate

__all__ = ["TrainConfig", "TrainResult", "train", "validate"]
