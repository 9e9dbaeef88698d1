"""Object knowledge: typical size, colour and shape of everyday objects by name (docs/knowledge.md).

The grounder scores each candidate by how likely its measured size, colour and shape are for the named
object (`grounding.score`, "Object knowledge"), so that "the tuna can" is told from "the coffee can" by size
and "the mustard bottle" from a ketchup bottle by colour.
"""

from prompose_grasp.perception.knowledge.table import (
    COARSE_SHAPES,
    TABLE_PATH,
    KnowledgeMatch,
    ObjectEntry,
    ObjectKnowledge,
    load_table,
)

__all__ = ["COARSE_SHAPES", "TABLE_PATH", "KnowledgeMatch", "ObjectEntry", "ObjectKnowledge", "load_table"]
