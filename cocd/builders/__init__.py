"""Scene builders: deterministic for a given seed."""

from __future__ import annotations

from cocd.builders._common import G as G  # the gravity the builders use, for the studies
from cocd.builders.columns import (
    box_3d,
    column_2d,
    column_collapse,
    grain_groups,
    stack,
    static_box,
)
from cocd.builders.hard import (
    HARD_CASES,
    fast_impact,
    heavy_on_light,
    jammed_box,
    size_ratio,
    tall_stack,
    wedged_grain,
    zero_gap,
)

__all__ = [
    "HARD_CASES",
    "box_3d",
    "column_2d",
    "column_collapse",
    "fast_impact",
    "grain_groups",
    "heavy_on_light",
    "jammed_box",
    "size_ratio",
    "stack",
    "static_box",
    "tall_stack",
    "wedged_grain",
    "zero_gap",
]
