"""Checking claims on a tournament's results: the report's side of ``formula_tourney.claims``.

``formula_tourney.claims`` declares what a claim is (its schema and the shipped sets); this
package checks declared claims against runs. ``sources`` picks the claims a report checks,
``entrants`` tells which runs are one entrant (so that like is compared with like),
``evaluate`` selects each side's runs and scores them, ``evidence`` turns the scores into a
verdict with its intervals, ``profiles`` computes performance profiles, ``table`` shows the
verdicts as a report table and ``figures`` draws what lies behind them.
"""
