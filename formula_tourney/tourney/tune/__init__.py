"""Optuna pre-selection of a variant's hyperparameters, before the tournament proper.

- ``spec``: the tune file's schema; ``study``: the Optuna plumbing shared by parent and workers;
- ``run``: the parent that creates a study and runs its trials (``run_tune``);
- ``worker``: one trial in a worker process; ``best_params``: ``--write-best``.
"""
