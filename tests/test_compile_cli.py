"""``formula-tourney compile`` (run by ``make setup``): the first tournament of a fresh checkout
must find the kernels in numba's cache instead of compiling them in every worker."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from formula_tourney.cli import main
from formula_tourney.lines import speed_profile
from formula_tourney.sim import kernels


def test_compile_fills_the_cache_of_the_kernels_a_run_uses(capsys: pytest.CaptureFixture) -> None:
    main(["compile", "--json"])
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert doc["compiled"] is True and doc["seconds"] > 0
    assert "compile:" in captured.err
    # the vector env's entry points (the rest inline into them) and the QSS line solver
    for dispatcher in (kernels.step_cars, kernels.derive_params, speed_profile._pass):
        index = Path(dispatcher._cache._cache_file._index_path)
        assert index.is_file(), index
        assert dispatcher.signatures, f"{dispatcher.__name__} was not compiled by the command"
