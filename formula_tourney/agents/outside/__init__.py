"""Outside entrants: drivers written elsewhere, raced beside the paper's families.

``naming`` turns what a tournament file or ``train`` names (``impl = "package.module:Class"``,
an entry point of the group ``formula_tourney.entrants``, ``sb3 = "SAC"``,
``sb3_contrib = "CrossQ"``) into an entrant class and its settings; ``check`` proves before any
job starts that the class satisfies ``agents.protocol.Entrant``, that its settings validate and
that it can act on one observation; ``sb3`` adapts any Stable-Baselines3 or sb3-contrib
algorithm to the protocol. This package stays in the ``agents`` layer: it knows no track, no
env and no results folder, so the loop, the tournament and the races all use it alike.
"""
