"""Claims: findings stated as comparisons between groups of runs, declared in data.

``claims.schema`` is the one model of a claim (what ``[claims]`` in a tournament file and a claims
file hold); the shipped sets (``paper.toml``: the paper's six findings) live next to it. The
report (``report.claims.evaluate``) evaluates them on a tournament's results.
"""
