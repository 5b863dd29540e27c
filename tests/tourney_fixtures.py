"""What the tournament tests share: a tiny tournament file whose jobs take seconds."""

from __future__ import annotations

# Small nets, small batches, updates from the first steps: each job is seconds, not minutes.
# Fill in with TINY.format(entrants='["WIN1", "MS2"]', p2="<more TOML, e.g. later parts>").
TINY = """\
name = "tiny"

[defaults]
seeds = 1
episodes = 2
max_steps = 30
test_every_episodes = 2
test_starts = 1
test_max_steps = 30
device = "cpu"

[variants.WIN1]
overrides = {{ hidden = [32, 32], batch_size = 16, learning_starts = 16 }}
[variants.MS2]
overrides = {{ hidden = [32, 32], batch_size = 16, learning_starts = 16 }}
[variants.PER40k]
overrides = {{ hidden = [32, 32], batch_size = 16, learning_starts = 16 }}

[[parts]]
name = "p1"
entrants = {entrants}
train_tracks = ["oval"]

{p2}"""
