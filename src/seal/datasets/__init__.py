"""Recorded demonstrations on disk: LeRobot-format datasets."""

from seal.datasets.lerobot import Episode, LeRobotReader, LeRobotWriter, open_dataset, validate_episode

__all__ = ["Episode", "LeRobotReader", "LeRobotWriter", "open_dataset", "validate_episode"]
