"""safeio.check_name: one path component, nothing else (a final newline used to pass)."""

from __future__ import annotations

import pytest

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import check_name, is_safe_name


@pytest.mark.parametrize(
    "name",
    ["bt\n", "bt\r\n", "a\tb", "x\x00", "a\x7fb", "tab\t", " lead", "a b", "../x", "a/b",
     "a\\b", "..", "a..b", ".hidden", "-dash", "", "é", "\u0661\u0662", "a" * 129, None, 3],
)
def test_unsafe_names_are_refused(name):
    assert not is_safe_name(name)
    with pytest.raises(UserInputError, match="invalid track name"):
        check_name(name, "track name")


@pytest.mark.parametrize("name", ["bt", "e-track-1", "gen-7", "a.b+c_d", "A" * 128, "9"])
def test_safe_names_pass_unchanged(name):
    assert is_safe_name(name)
    assert check_name(name) == name
