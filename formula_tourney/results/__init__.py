"""The results layout: job folders and tournament folders, their files, columns and metrics.

One package owns what is on disk so that the trainer (writer), the tournament store, the runner's
metrics and the report (readers) cannot disagree on a file or column name (docs/CONTRACTS.md).
"""
