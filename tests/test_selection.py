import numpy as np
import pytest

from babblegen.selection import binary_tournament, crowding_distance, non_dominated_sort, nsga2_select

# Two maximised objectives.
#   0 (1, 5)  1 (2, 4)  2 (3, 3)  3 (4, 1)   mutually non-dominated: front 0
#   5 (2, 2)  6 (3, 0.5)                      dominated only by front-0 points: front 1
#   4 (1, 1)                                  dominated by 5 (2, 2) as well: front 2
TWO = np.array([[1, 5], [2, 4], [3, 3], [4, 1], [1, 1], [2, 2], [3, 0.5]])
# Crowding in front 0 (extremes 0 and 3 are infinite on each objective):
#   objective 1 (1, 2, 3, 4; span 3):  1 -> (3 - 1) / 3 = 2/3,  2 -> (4 - 2) / 3 = 2/3
#   objective 2 (5, 4, 3, 1; span 4):  1 -> (5 - 3) / 4 = 1/2,  2 -> (4 - 1) / 4 = 3/4
#   totals: 1 -> 7/6, 2 -> 17/12; fronts of one or two members are all infinite.


def test_non_dominated_sort_two_objectives():
    np.testing.assert_array_equal(non_dominated_sort(TWO), [0, 0, 0, 0, 2, 1, 1])


def test_crowding_distance_two_objectives():
    crowd = crowding_distance(TWO, non_dominated_sort(TWO))
    assert np.isinf(crowd[[0, 3, 4, 5, 6]]).all()
    np.testing.assert_allclose(crowd[[1, 2]], [7 / 6, 17 / 12])


@pytest.mark.parametrize(
    ("n_keep", "expected"),
    [
        (2, [0, 3]),  # the two infinite-crowding extremes of front 0
        (3, [0, 3, 2]),  # then 2 (17/12) before 1 (7/6)
        (4, [0, 3, 2, 1]),  # all of front 0
        (5, [0, 3, 2, 1, 5]),  # front 1: 5 and 6 both infinite, lower index first
        (7, [0, 3, 2, 1, 5, 6, 4]),
    ],
)
def test_nsga2_select_two_objectives(n_keep, expected):
    np.testing.assert_array_equal(nsga2_select(TWO, n_keep), expected)


def test_nsga2_select_one_objective_is_elitist_truncation():
    values = np.array([3.0, 7.0, 7.0, 1.0, 5.0, 7.0])
    np.testing.assert_array_equal(non_dominated_sort(values[:, None]), [2, 0, 0, 3, 1, 0])
    np.testing.assert_array_equal(nsga2_select(values[:, None], 2), [1, 2])  # ties to lower index
    np.testing.assert_array_equal(nsga2_select(values[:, None], 3), [1, 2, 5])
    np.testing.assert_array_equal(nsga2_select(values[:, None], 4), [1, 2, 5, 4])
    np.testing.assert_array_equal(nsga2_select(values, 6), [1, 2, 5, 4, 0, 3])


def test_nsga2_select_one_objective_matches_sorting_on_random_data():
    rng = np.random.default_rng(0)
    for _ in range(50):
        values = rng.integers(0, 10, size=24).astype(float)
        expected = np.lexsort((np.arange(24), -values))[:12]
        np.testing.assert_array_equal(nsga2_select(values[:, None], 12), expected)


def test_nsga2_select_validates():
    with pytest.raises(ValueError):
        nsga2_select(TWO, 8)
    with pytest.raises(ValueError):
        nsga2_select(np.array([[1.0], [np.nan]]), 1)


def test_binary_tournament_rank_decides():
    rank = np.array([2, 0, 3, 1])  # 1 is best, 2 is worst
    crowd = np.zeros(4)
    winners = binary_tournament(rank, crowd, 20_000, np.random.default_rng(0))
    freq = np.bincount(winners, minlength=4) / winners.size
    # two distinct contestants out of four: an individual wins when drawn against a worse one.
    # P(in the pair) = 1/2, and it beats 3, 2, 1, 0 of the 3 others: win rates 3/6, 2/6, 1/6, 0
    np.testing.assert_allclose(freq[[1, 3, 0, 2]], [3 / 6, 2 / 6, 1 / 6, 0.0], atol=0.015)
    assert freq[2] == 0.0


def test_binary_tournament_crowding_breaks_rank_ties():
    rank = np.zeros(3, dtype=int)
    crowd = np.array([0.5, np.inf, 0.1])
    winners = binary_tournament(rank, crowd, 9000, np.random.default_rng(1))
    freq = np.bincount(winners, minlength=3) / winners.size
    # pairs {0,1}, {0,2}, {1,2} equally likely: 1 wins two of them, 0 one, 2 none
    np.testing.assert_allclose(freq, [1 / 3, 2 / 3, 0.0], atol=0.02)


def test_binary_tournament_single_individual():
    winners = binary_tournament(np.zeros(1), np.zeros(1), 5, np.random.default_rng(0))
    np.testing.assert_array_equal(winners, 0)
