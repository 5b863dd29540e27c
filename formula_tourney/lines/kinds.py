"""The names of the reference lines, and the one label each shows in entrant names and tables.

Run specs, tournament and claims files, the CLI and the report all take a line by these names;
this module imports nothing, so that every layer (claims files included) can type a line with
it. The labels are the paper's (MOT = middle of track, RC = the racing line the Tita bot drove)
and the short ones entrant names carry (``WIN1-MC-LAC``): a table shows the same tag.
"""

from __future__ import annotations

from typing import Literal, get_args

ReferenceKind = Literal["centre", "recorded", "mincurv"]
"""A line a run drives against (reward, telemetry, LAC) and a baseline follower can follow."""
REFERENCE_KINDS: tuple[str, ...] = get_args(ReferenceKind)

LineKind = Literal[ReferenceKind, "genetic"]
"""Every line ``lines.registry`` computes; the genetic line is the genetic bot's own."""
LINE_KINDS: tuple[str, ...] = get_args(LineKind)

LINE_LABELS: dict[str, str] = {"centre": "MOT", "recorded": "RC", "mincurv": "MC",
                               "genetic": "GenLine"}
"""centre = the paper's MOT; recorded = the paper's RC; mincurv = minimum curvature."""


def line_label(kind: str) -> str:
    """The label of line ``kind`` (the name itself for a line this module does not know)."""
    return LINE_LABELS.get(str(kind), str(kind))
