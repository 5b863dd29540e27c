"""tourney."""
