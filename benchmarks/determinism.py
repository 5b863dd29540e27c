"""Whether two results folders hold the same runs: a digest of every job table, file by file.

The same seed must give the same lap times on the same machine, and a refactor must keep them.
This reads every ``*.parquet`` job table and baseline ``result.json`` under two results folders
(e.g. ``make demo`` run once on the code before a change and once after, with numba's kernel
cache filled by ``make setup`` on both sides), leaves out the columns that measure time on the
machine (CPU and wall seconds, timestamps, process ids), and compares a digest of the rest.

    .venv/bin/python benchmarks/determinism.py BEFORE/quick AFTER/quick

The anchor is the first folder. The last line is one JSON object: files compared, identical,
their share, and the files that differ or stand on one side only.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import pandas as pd

MACHINE_TIME_KEYS = frozenset({
    "seconds", "wall_s", "started_at", "finished_at", "worker_pid", "train_seconds", "cpu_s",
})  # fmt: skip
"""Columns and keys that measure the machine, not the run: they differ between equal runs."""


def file_digest(path: Path) -> str:
    """Digest of one job table (or baseline result) without :data:`MACHINE_TIME_KEYS`."""
    if path.suffix == ".parquet":
        frame = pd.read_parquet(path)
        frame = frame[[c for c in frame.columns if c not in MACHINE_TIME_KEYS]]
        text = frame.to_csv(index=False)
    else:
        data = json.loads(path.read_text(encoding="utf-8"))
        text = json.dumps({k: v for k, v in data.items() if k not in MACHINE_TIME_KEYS},
                          sort_keys=True)  # fmt: skip
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def folder_digests(root: Path) -> dict[str, str]:
    """Relative path -> digest for every job table and baseline result under ``root``."""
    paths = sorted([*root.rglob("*.parquet"), *root.rglob("result.json")])
    return {str(p.relative_to(root)): file_digest(p) for p in paths}


def compare(before: dict[str, str], after: dict[str, str]) -> dict[str, object]:
    """The comparison the last line prints."""
    shared = sorted(set(before) & set(after))
    differ = [name for name in shared if before[name] != after[name]]
    return {
        "benchmark": "determinism",
        "files": len(shared),
        "identical": len(shared) - len(differ),
        "identical_share": round((len(shared) - len(differ)) / len(shared), 4) if shared else None,
        "differ": differ,
        "only_before": sorted(set(before) - set(after)),
        "only_after": sorted(set(after) - set(before)),
        "goal_identical_share": 1.0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="*", type=Path, help="BEFORE AFTER results folders; none "
                    "(as `make bench` runs it): nothing to compare, an empty result")
    args = ap.parse_args()
    if len(args.folders) not in (0, 2):
        ap.error("give two results folders (BEFORE AFTER), or none")
    if not args.folders:
        print("determinism: no folders given, nothing to compare", file=sys.stderr)
        print(json.dumps(compare({}, {})))
        return
    before, after = (folder_digests(folder) for folder in args.folders)
    for name in sorted(set(before) | set(after)):
        print(f"{before.get(name, '-'):16}  {after.get(name, '-'):16}  {name}", file=sys.stderr)
    print(json.dumps(compare(before, after)))


if __name__ == "__main__":
    main()
