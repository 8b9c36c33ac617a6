"""The search strategies' interface checked: `search_strategy.SearchStrategy` by `isinstance` (the methods
are there) and by signature (each method takes the Protocol's parameters, by the same names)."""
from __future__ import annotations

import inspect

from wosac_eval.features.search_strategy import SearchStrategy

METHODS = ("nearest_object", "time_to_collision", "road_edge_distance", "red_light_violation")


def parameter_names(function) -> list[str]:
    return [p for p in inspect.signature(function).parameters if p != "self"]


def assert_is_search_strategy(search) -> None:
    assert isinstance(search, SearchStrategy), type(search).__name__
    for method in METHODS:
        assert parameter_names(getattr(type(search), method)) == parameter_names(getattr(SearchStrategy, method)), \
            (type(search).__name__, method)
