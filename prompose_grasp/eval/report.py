"""Plain-text tables of metric dicts, for terminals, logs and docs."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.eval.nocs import NOCS_METRIC_KEYS

__all__ = ["format_nocs_table", "write_report_json"]


def _cell(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    return f"{float(value):.1f}"


def format_nocs_table(
    table: Mapping[str, Any], title: str = "NOCS mAP", keys: Sequence[str] = NOCS_METRIC_KEYS
) -> str:
    """Format a `compute_nocs_map` result as a plain-text table: one row per class, then the mean.

    Args:
        table: {"mean": {key: AP %}, "per_class": {name: {key: AP %}}}.
        title: first line of the output.
        keys: metric columns, in order.
    Returns:
        the table as lines joined by newlines (no trailing newline); values with one decimal, "n/a" for NaN.
    Raises:
        InvalidInputError: `table` lacks "mean" / "per_class" or a row lacks one of `keys`.
    """
    if not isinstance(table, Mapping) or "mean" not in table or "per_class" not in table:
        raise InvalidInputError(
            'table must be a dict with "mean" and "per_class", as compute_nocs_map returns'
        )
    rows = [*table["per_class"].items(), ("mean", table["mean"])]
    for name, row in rows:
        absent = [k for k in keys if k not in row]
        if absent:
            raise InvalidInputError(f"table row {name!r} lacks metric(s) {', '.join(absent)}")
    name_width = max(len("class"), *(len(str(name)) for name, _ in rows))
    widths = [max(6, len(k)) for k in keys]
    header = "  ".join([f"{'class':<{name_width}}", *(f"{k:>{w}}" for k, w in zip(keys, widths))])
    rule = "-" * len(header)
    lines = [title, header, rule]
    for name, row in rows:
        if name == "mean":
            lines.append(rule)
        cells = [f"{_cell(row[k]):>{w}}" for k, w in zip(keys, widths)]
        lines.append("  ".join([f"{name!s:<{name_width}}", *cells]))
    return "\n".join(lines)


def write_report_json(report: Mapping[str, Any], path: str | Path) -> None:
    """Write a benchmark report as JSON (numpy scalars as floats), creating the folder if needed."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1, default=float))
