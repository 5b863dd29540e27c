"""The results layout: job folders and tournament folders, their files, columns and metrics.

One package owns what is on disk so that the trainer (writer), the tournament store, the runner's
metrics and the report (readers) cannot disagree on a file or column name (docs/CONTRACTS.md).
``layout`` names the files and columns; ``folder`` reads and writes job, baseline and race
folders; ``index`` reads the tournament's index; ``identity`` says which runs are one sample;
``metrics`` (bLT, aLT, clean laps, the general model) and ``competence`` (CPU-seconds to each
milestone) compute each number once for every table, figure and promotion rule.
"""
