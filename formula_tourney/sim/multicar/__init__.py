"""Several cars on one track that touch and see each other: the simulator side of a race.

``lockstep_kernels`` advances N cars substep by substep with car-car contact and opponent
sensors, ``simulator`` holds their arrays (``RaceSim``), ``frames`` draws race frames. Races'
rules (grid, laps, classification) live in ``formula_tourney.race``.
"""
