"""Tournaments: declarative files turned into training jobs, run on a pool or Ray, and promoted.

Modules, in the order data flows through them (imports go the same way):

- ``spec``: the tournament file's schema and line-accurate errors.
- ``plan``: parts -> entrants x setups x seeds -> jobs, each with its ``training.run_spec.RunSpec``;
  ``jobs``: the picklable ``Job``.
- ``store``: the index (``index.sqlite``); ``outcomes``: a finished folder's metrics;
  ``race_part``/``race_worker``: a race series, parent and worker side.
- ``kinds/``: one object per job kind (training run, baseline drive, race series) that makes,
  runs and records its jobs; ``runner``: one job in a worker; ``executors``: where jobs run.
- ``promote``: who goes on; ``scheduler``: the parent's loop; ``summary``: the tournament's
  state as plain data.
- ``api``: ``run_tournament``; ``tune/``: Optuna studies (and ``--write-best``);
  ``estimate/``: the cost before a run; ``lock``: one run per results folder.
"""
