"""Reports: the paper's tables, statistics and figures from a tournament's results folder.

``load`` reads the results (files only, through ``results.index`` and ``results.folder``);
``paper_tables`` builds Tables 1-3 and the comparisons from ``results.metrics`` into the table
model of ``table_model``, as ``grip_table``, ``competence_table`` (time to competence, from
``results.competence``), ``cost`` and ``race_table`` build theirs; ``renderers`` (terminal,
Markdown, LaTeX) and ``html`` write them; ``stats`` holds the confidence intervals; ``plots``
draws the figures; ``claims`` checks the declared claims; ``build`` ties them together for the
CLI. Nothing here trains, drives or imports the tournament runner.
"""
