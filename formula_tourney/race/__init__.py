"""Races: entrants' drivers and bots on one track at once, and the result as motorsport gives it."""
