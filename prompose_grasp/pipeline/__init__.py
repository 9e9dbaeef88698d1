"""Pick-and-place orchestration: free-text commands, the closed loop, typed outcomes and progress events."""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.pipeline.command import Command, CommandNotUnderstood, CommandParser
    from prompose_grasp.pipeline.outcome import REASONS, PickOutcome, ProgressEvent
    from prompose_grasp.pipeline.pick_and_place import PickAndPlace, PickConfig

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.pipeline.command": (
            "Command",
            "CommandNotUnderstood",
            "CommandParser",
        ),
        "prompose_grasp.pipeline.outcome": (
            "REASONS",
            "PickOutcome",
            "ProgressEvent",
        ),
        "prompose_grasp.pipeline.pick_and_place": (
            "PickAndPlace",
            "PickConfig",
        ),
    },
    submodules=(
        "command",
        "describe",
        "outcome",
        "pick_and_place",
    ),
)

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
