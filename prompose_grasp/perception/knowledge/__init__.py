"""Object knowledge: typical size, colour and shape of everyday objects by name (docs/knowledge.md).

The grounder scores each candidate by how likely its measured size, colour and shape are for the named
object (`grounding.score`, "Object knowledge"), so that "the tuna can" is told from "the coffee can" by size
and "the mustard bottle" from a ketchup bottle by colour.
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.perception.knowledge.table import (
        COARSE_SHAPES,
        TABLE_PATH,
        KnowledgeMatch,
        ObjectEntry,
        ObjectKnowledge,
        load_table,
    )

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.perception.knowledge.table": (
            "COARSE_SHAPES",
            "TABLE_PATH",
            "KnowledgeMatch",
            "ObjectEntry",
            "ObjectKnowledge",
            "load_table",
        ),
    },
    submodules=("table",),
)

__all__ = ["COARSE_SHAPES", "TABLE_PATH", "KnowledgeMatch", "ObjectEntry", "ObjectKnowledge", "load_table"]
