"""Track surfaces: TORCS surface names to friction and rolling resistance (docs/sim.md).

Our track model is asphalt, then ``grass_width_m`` of side, then walls. Each track sample has a
road surface and a side surface; a surface's friction is a multiplier on the car's ``mu`` (its
asphalt friction) and its rolling resistance an extra coefficient added to the car's
``rolling_resistance``. Road default asphalt: 1.0 and 0.0. Side default grass: NaN, the car's
own ``mu_grass`` (with its grass drag, which every side keeps), and 0.0. A track without surface
names drives exactly as before.

The numbers are TORCS' own: :data:`TORCS_SURFACES` is ``friction`` and ``rolling resistance`` of
every surface in torcs-data's ``data/tracks/surfaces.xml`` (version 1.20, 2004). A name's
multiplier is its friction over asphalt's (1.2); its extra rolling resistance is its TORCS
coefficient less asphalt's (0.001) on the road, less grass's (0.01) on the side, where the car's
grass drag already stands for grass (never below 0). A name not in the table is matched by the
first family word in it (``dirtA``, ``newdirt``, ``dirt-d2`` -> ``dirt``; ``grass-w2`` ->
``grass``; ``spring-road1`` -> ``road1``; ``b-pits`` -> ``asphalt-pits``); a name still unknown
gets the default (asphalt on the road, the car's grass on the side) with a warning naming the
file and the surface. On the side, any surface of grass's friction (0.4: ``grass6``,
``side-grass``) keeps the car's own ``mu_grass``; only its extra rolling resistance counts.
"""

from __future__ import annotations

import math
import re
import warnings

import numpy as np

TORCS_SURFACES: dict[str, tuple[float, float]] = {
    "asphalt-lines": (1.2, 0.001), "asphalt-l-left": (1.2, 0.001),
    "asphalt-l-right": (1.2, 0.001), "asphalt-l-both": (1.2, 0.001),
    "asphalt-pits": (1.2, 0.05), "asphalt": (1.2, 0.001), "concrete2": (1.0, 0.002),
    "concrete": (0.8, 0.0035), "concrete3": (0.7, 0.003), "concrete4": (1.1, 0.0015),
    "b-concrete4-concrete-l1": (0.9, 0.002), "b-concrete4-concrete-l1p": (0.9, 0.002),
    "concrete-pits": (1.1, 0.05), "grass": (0.4, 0.01), "sand": (0.6, 0.1),
    "dirt": (0.9, 0.006), "dirt-b": (0.8, 0.006), "asphalt2-lines": (1.4, 0.0012),
    "asphalt2-l-left": (1.4, 0.0012), "asphalt2-l-right": (1.4, 0.0012),
    "asphalt2-l-both": (1.4, 0.0012), "curb-5cm-r": (1.4, 0.0025), "curb-5cm-l": (1.4, 0.0025),
    "curb-l": (1.4, 0.0025), "grass5": (0.4, 0.01), "grass3": (0.4, 0.01),
    "tar-grass3-l": (1.0, 0.005), "tar-grass3-r": (1.0, 0.005), "tar-sand": (1.0, 0.01),
    "asphalt2": (1.25, 0.001), "road1": (1.1, 0.002), "road1-pits": (1.2, 0.05),
    "road1-asphalt": (1.1, 0.001), "asphalt-road1": (1.1, 0.001), "b-road1": (1.0, 0.002),
    "b-road1-l2": (0.8, 0.002), "b-road1-l2p": (0.8, 0.002), "grass6": (0.4, 0.015),
    "b-road1-grass6": (0.7, 0.005), "b-road1-grass6-l2": (0.7, 0.005),
    "b-road1-gravel-l2": (0.7, 0.05), "gravel": (0.6, 0.15), "sand3": (0.6, 0.12),
    "b-road1-sand3": (0.9, 0.01), "b-road1-sand3-l2": (0.8, 0.01), "grass7": (0.4, 0.015),
    "b-asphalt": (1.2, 0.001), "b-asphalt-l1": (1.2, 0.001), "b-asphalt-l1p": (1.2, 0.001),
    "b-asphalt-grass7": (0.8, 0.005), "b-asphalt-grass7-l1": (0.8, 0.005),
    "b-asphalt-grass6": (0.8, 0.005), "b-asphalt-grass6-l1": (0.8, 0.005),
    "b-asphalt-sand3": (1.0, 0.01), "b-asphalt-sand3-l1": (1.0, 0.01),
}
"""TORCS surface name -> (friction, rolling resistance), from torcs-data surfaces.xml."""

FAMILIES = {"asphalt": "asphalt", "tar": "asphalt", "road": "road1", "concrete": "concrete",
            "grass": "grass", "sand": "sand", "dirt": "dirt", "gravel": "gravel",
            "curb": "curb-l", "pit": "asphalt-pits"}
"""Leading word of an unlisted name -> the listed surface it drives like."""

_FAMILY = re.compile("|".join(sorted(FAMILIES, key=len, reverse=True)))
ROAD_DEFAULT = "asphalt"
SIDE_DEFAULT = "grass"
SurfaceTable = dict[str, tuple[float, float]]


def lookup(name: str, table: SurfaceTable | None = None, where: str = "track",
           warn: bool = True) -> tuple[float, float] | None:
    """TORCS (friction, rolling resistance) of ``name``; None (with a warning naming ``where``
    and the name) when neither the name nor its leading word is known."""
    merged = TORCS_SURFACES if not table else {**TORCS_SURFACES, **table}
    if name in merged:
        return merged[name]
    word = _FAMILY.search(name.lower())
    if word:
        return merged[FAMILIES[word.group(0)]]
    if warn:
        warnings.warn(f"{where}: unknown surface {name!r}; driving it as the default "
                      "(asphalt on the road, grass on the side)", stacklevel=3)
    return None


def road_coefficients(name: str, table: SurfaceTable | None = None, where: str = "track"
                      ) -> tuple[float, float]:
    """(friction multiplier on ``mu``, extra rolling resistance) of a road surface."""
    if not name or name == ROAD_DEFAULT:
        return 1.0, 0.0
    found = lookup(name, table, where)
    if found is None:
        return 1.0, 0.0
    f0, r0 = TORCS_SURFACES[ROAD_DEFAULT]
    return found[0] / f0, max(found[1] - r0, 0.0)


def side_coefficients(name: str, table: SurfaceTable | None = None, where: str = "track"
                      ) -> tuple[float, float]:
    """(friction multiplier on ``mu``, extra rolling resistance) of a side surface; NaN: the
    car's own ``mu_grass`` (the default grass, any surface of grass's friction, or an unknown
    name)."""
    if not name or name == SIDE_DEFAULT:
        return math.nan, 0.0
    found = lookup(name, table, where)
    if found is None:
        return math.nan, 0.0
    grass_f, grass_rr = TORCS_SURFACES[SIDE_DEFAULT]
    extra = max(found[1] - grass_rr, 0.0)
    if found[0] == grass_f:  # a grass: the car's own grass grip, whatever its name
        return math.nan, extra
    return found[0] / TORCS_SURFACES[ROAD_DEFAULT][0], extra


def sample_surfaces(road: list[str], side: list[str], which: np.ndarray,
                    table: SurfaceTable | None = None, where: str = "track"
                    ) -> tuple[np.ndarray, ...] | None:
    """Per-sample (road friction, side friction, road rolling, side rolling) for samples in
    segments ``which`` (road/side: one name per segment, "" for the default); None when every
    segment has the defaults (the track then carries no surface arrays)."""
    if not any(road) and not any(side):
        return None
    road_of = {n: road_coefficients(n, table, where) for n in dict.fromkeys(road)}
    side_of = {n: side_coefficients(n, table, where) for n in dict.fromkeys(side)}
    r = np.array([road_of[n] for n in road]).reshape(-1, 2)
    s = np.array([side_of[n] for n in side]).reshape(-1, 2)
    return r[which, 0], s[which, 0], r[which, 1], s[which, 1]
