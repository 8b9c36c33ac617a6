"""The pruned search is a `SearchStrategy`, and the interface check tells one that is not.

The JAX strategies (`DenseSearch`, `HostSearch`) are checked with the JAX tests
(tests/parity/test_jax_kernels.py), which run last.
"""
import numpy as np

from support.strategies import assert_is_search_strategy, parameter_names
from wosac_eval.features import road_edge
from wosac_eval.features.search import PrunedSearch
from wosac_eval.features.search_strategy import SearchStrategy


def test_pruned_search_is_a_search_strategy():
    table = road_edge.build_segment_table([np.array([[0, 0, 0], [10, 0, 0]], np.float32)])
    assert_is_search_strategy(PrunedSearch(table, None, None))


class MissingRedLights:
    def nearest_object(self, x, y, length, width, cos_h, sin_h, valid, num_evaluated):
        return x

    def time_to_collision(self, inputs):
        return inputs.x

    def road_edge_distance(self, x, y, bottom, length, width, cos_h, sin_h, valid):
        return x


def test_a_class_without_every_search_is_not_a_strategy():
    assert not isinstance(MissingRedLights(), SearchStrategy)


def test_time_to_collision_takes_one_argument():
    assert parameter_names(SearchStrategy.time_to_collision) == ["inputs"]
