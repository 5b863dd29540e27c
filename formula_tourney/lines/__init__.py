"""Reference lines and the reference limit: what a car is rewarded to follow, and how fast a lap
could be.

``kinds`` names the lines; ``centre``, ``mincurv`` (a QP), ``recorded`` and ``genetic`` make them;
``registry`` is the one entry point (cached on disk); ``surface`` and ``speed_profile`` give the
quasi-steady-state lap of a line, ``limit`` the track's reference limit, ``lac`` the look-ahead
curvature, ``lap_loss`` where a driven lap loses time against a profile. Nothing here drives a
bot (``bots.line_offsets`` adds the lines a bot must drive).
"""
