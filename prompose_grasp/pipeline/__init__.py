"""Pick-and-place orchestration: free-text commands, the closed loop, typed outcomes and progress events."""

from prompose_grasp.pipeline.command import Command, CommandNotUnderstood, CommandParser
from prompose_grasp.pipeline.outcome import REASONS, PickOutcome, ProgressEvent
from prompose_grasp.pipeline.pick_and_place import PickAndPlace, PickConfig

__all__ = [
    "REASONS",
    "Command",
    "CommandNotUnderstood",
    "CommandParser",
    "PickAndPlace",
    "PickConfig",
    "PickOutcome",
    "ProgressEvent",
]
