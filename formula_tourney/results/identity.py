"""Which stored runs are the same training: the run specification less its test settings.

Tests drive their own envs from their own seeds and never feed the learner, so two runs whose
specifications differ only in where, how often or how long they are tested train the same
agent step for step (``tests/test_claims.py`` checks it on real runs). This module owns that
list of keys, and works on the plain JSON a job's ``config.json`` holds, so the report can tell
repeats apart without building a ``training.run_spec.RunSpec`` (which sits above it).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

TEST_ONLY_KEYS = ("test_tracks",)
"""Top-level run-spec keys that change the tests and never the training."""
TEST_ONLY_SCHEDULE_KEYS = ("test_every_episodes", "test_starts", "test_max_steps",
                           "save_test_checkpoints", "test_grip_scales", "resume_every_cpu_s")
"""Schedule keys that change the tests (or how often a job saves where it is) and never the
training."""


def training_digest(run_spec: Mapping[str, Any]) -> str:
    """Short hash of what a run's training depends on (its JSON run spec, tests left out)."""
    data = {k: v for k, v in run_spec.items() if k not in TEST_ONLY_KEYS}
    schedule = data.get("schedule")
    if isinstance(schedule, Mapping):
        data["schedule"] = {k: v for k, v in schedule.items()
                            if k not in TEST_ONLY_SCHEDULE_KEYS}  # fmt: skip
    text = json.dumps(data, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]
