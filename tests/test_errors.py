"""show(): how a message quotes a value, bounded whatever the value holds."""

from __future__ import annotations

import pytest

from pedcal.errors import show


@pytest.mark.parametrize("limit", [10, 40, 100])
def test_a_nest_of_long_strings_is_cut_to_four_times_the_limit(limit):
    """Each item was cut and each level bounded, but not the whole: a 10 x 10 nest of 50-character
    strings printed ~1000 characters into a one-line message."""
    nest = [[f"{i}{j}" + "x" * 48 for j in range(10)] for i in range(10)]
    text = show(nest, limit)
    assert text.startswith("[['00xxx") and text.endswith("...")
    assert len(text) == 4 * limit + 3
    assert "\n" not in text


def test_a_container_within_the_bound_is_whole():
    assert show([1, "ab", [2.5, None]]) == "[1, 'ab', [2.5, None]]"
    assert show(list(range(6)), 10) == "[0, 1, 2, 3, 4, 5]"            # 18 characters, within 4 * 10


def test_none_inside_a_container_reads_none_not_the_text_none():
    assert show([None, "None"]) == "[None, 'None']"
    assert show({"k": None}) == "{'k': None}"
    assert show((None,)) == "(None,)"
