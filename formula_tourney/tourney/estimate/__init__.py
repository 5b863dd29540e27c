"""What a tournament will cost before it runs: the cost model and its measured rates.

- ``calibrate``: the rates measured on this machine (env step, update, test lap, checkpoint);
- ``model``: one job's cost and the scheduler's wall time replayed;
- ``plan``: a planned tournament priced job by job (``estimate_plan``).
"""

MIN_CALIBRATE_S = 0.5
"""Shortest ``--calibrate-s``: the measurement times exploring steps until the buffer holds a
batch, then at least three chunks of updates, a test episode and a checkpoint save; below half
a second the fixed parts (env build, first test) are most of it and the update timing rests
on three chunks of ten updates, so the estimate moves with the measurement's length."""
