"""Pick-and-place orchestration: free-text commands, the closed loop, typed outcomes and progress events."""

from prompose_grasp.pipeline.command import Command, CommandNotUnderstood, CommandParser

__all__ = ["Command", "CommandNotUnderstood", "CommandParser"]
