"""What a tournament will cost before it runs: the cost model and its measured rates.

- ``calibrate``: the rates measured on this machine (env step, update, test lap, checkpoint);
- ``model``: one job's cost and the scheduler's wall time replayed;
- ``plan``: a planned tournament priced job by job (``estimate_plan``).
"""
