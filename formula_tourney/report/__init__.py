"""Reports: the paper's tables, statistics and figures from a tournament's results folder.

``load`` reads the store (files only), ``tables``/``stats`` compute and format the numbers,
``plots``/``html`` draw and assemble, ``build`` ties them together for the CLI, and ``replay``
turns a checkpoint's lap into a GIF. Nothing here trains or imports the tournament runner.
"""
