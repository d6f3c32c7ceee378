from collections import Counter

import numpy as np
import pytest

from babblegen.genome import (
    as_genome,
    crossover,
    extend,
    gaussian_mutation,
    random_genome,
    remove_waypoint,
    waypoint_mutation,
)


class FixedRng:
    """Stands in for np.random.Generator where an operator's single draw must be fixed."""

    def __init__(self, integer: int = 0, uniform: float = 0.0) -> None:
        self.integer = integer
        self.uniform = uniform

    def integers(self, high: int) -> int:
        assert 0 <= self.integer < high
        return self.integer

    def random(self) -> float:
        return self.uniform


def test_random_genome_is_one_final_point_in_unit_cube():
    rng = np.random.default_rng(0)
    genomes = np.stack([random_genome(rng) for _ in range(2000)])
    assert genomes.shape == (2000, 1, 3)
    assert genomes.dtype == np.float64
    assert genomes.min() >= 0.0 and genomes.max() < 1.0
    # uniform on [0, 1): mean 0.5, standard error 0.29 / sqrt(2000) ~ 0.0065 per coordinate
    np.testing.assert_allclose(genomes.mean(axis=(0, 1)), 0.5, atol=0.03)


def test_gaussian_mutation_adds_noise_to_every_coordinate_without_clipping():
    genome = np.array([[0.0, 0.5, 1.0], [0.9, 0.95, 1.0]])
    before = genome.copy()
    child = gaussian_mutation(genome, 0.3, np.random.default_rng(1))
    np.testing.assert_array_equal(genome, before)  # input untouched
    assert child.shape == genome.shape
    assert np.all(child != genome)

    big = np.full((5000, 3), 0.5)
    noise = gaussian_mutation(big, 0.3, np.random.default_rng(2)) - big
    assert abs(noise.mean()) < 0.01
    assert abs(noise.std() - 0.3) < 0.01
    # about 9.6 % of N(0.5, 0.3) samples fall outside [0, 1] (|z| > 1.667); none is clipped back
    outside = np.mean((big + noise < 0.0) | (big + noise > 1.0))
    assert 0.08 < outside < 0.11


def test_gaussian_mutation_with_zero_sigma_is_a_copy():
    genome = np.array([[0.1, 0.2, 0.3]])
    child = gaussian_mutation(genome, 0.0, np.random.default_rng(0))
    np.testing.assert_array_equal(child, genome)
    assert child is not genome


@pytest.mark.parametrize(
    ("segment", "expected"),
    [
        # sequence: start (0,0,0) -> w0 (1,1,1) -> w1 (3,5,7)
        (0, [[0.5, 0.5, 0.5], [1, 1, 1], [3, 5, 7]]),  # midpoint of start and w0
        (1, [[1, 1, 1], [2, 3, 4], [3, 5, 7]]),  # midpoint of w0 and w1: ((1+3)/2, (1+5)/2, (1+7)/2)
    ],
)
def test_extend_inserts_exact_midpoint_of_chosen_segment(segment, expected):
    start = np.zeros(3)
    genome = np.array([[1.0, 1.0, 1.0], [3.0, 5.0, 7.0]])
    child = extend(genome, start, FixedRng(integer=segment))
    np.testing.assert_array_equal(child, np.array(expected, dtype=float))
    assert genome.shape == (2, 3)  # input untouched


def test_extend_one_waypoint_genome_uses_start():
    start = np.array([0.2, -0.4, 1.0])
    genome = np.array([[0.6, 0.4, 0.0]])
    child = extend(genome, start, np.random.default_rng(0))
    np.testing.assert_allclose(child, [[0.4, 0.0, 0.5], [0.6, 0.4, 0.0]])


def test_extend_chooses_segments_uniformly_and_keeps_final_point():
    start = np.zeros(3)
    genome = np.array([[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])
    rng = np.random.default_rng(3)
    inserted = []
    for _ in range(3000):
        child = extend(genome, start, rng)
        assert child.shape == (4, 3)
        np.testing.assert_array_equal(child[-1], genome[-1])
        # the new x is one of the segment midpoints 0.5, 1.5, 2.5
        new_x = sorted(set(child[:, 0]) - set(genome[:, 0]))
        assert len(new_x) == 1
        inserted.append(new_x[0])
    values, counts = np.unique(inserted, return_counts=True)
    np.testing.assert_array_equal(values, [0.5, 1.5, 2.5])
    assert np.all(np.abs(counts / 3000 - 1 / 3) < 0.04)


def test_crossover_splices_at_same_relative_cut():
    a = np.arange(12, dtype=float).reshape(4, 3)  # rows a0..a3
    b = -np.arange(1, 7, dtype=float).reshape(2, 3)  # rows b0, b1
    # u = 0.5: first floor(0.5 * 4) = 2 rows of a, then b from floor(0.5 * 2) = 1 on
    child = crossover(a, b, FixedRng(uniform=0.5))
    np.testing.assert_array_equal(child, np.vstack([a[:2], b[1:]]))
    # u = 0: the child is b
    np.testing.assert_array_equal(crossover(a, b, FixedRng(uniform=0.0)), b)
    # u = 0.99: a[:3] then b[1:]
    np.testing.assert_array_equal(crossover(a, b, FixedRng(uniform=0.99)), np.vstack([a[:3], b[1:]]))


def test_crossover_lengths_stay_between_parents():
    rng = np.random.default_rng(4)
    a, b = np.zeros((6, 3)), np.ones((2, 3))
    for _ in range(500):
        child = crossover(a, b, rng)
        assert 2 <= child.shape[0] <= 6
        np.testing.assert_array_equal(child[-1], b[-1])


def test_as_genome_rejects_bad_shapes():
    for bad in (np.zeros(3), np.zeros((0, 3)), np.zeros((2, 2))):
        with pytest.raises(ValueError):
            as_genome(bad)


def test_waypoint_mutation_moves_one_waypoint_by_the_same_noise_as_gaussian_mutation():
    genome = np.arange(15, dtype=float).reshape(5, 3)
    moved_rows = []
    for seed in range(200):
        child = waypoint_mutation(genome, 0.3, np.random.default_rng(seed))
        changed = np.flatnonzero(np.any(child != genome, axis=1))
        assert len(changed) == 1, "exactly one waypoint changes"
        moved_rows.append(int(changed[0]))
    counts = np.bincount(moved_rows, minlength=5)
    assert counts.min() >= 20, counts  # each of the 5 waypoints is chosen (expected 40 each)
    one = np.array([[0.2, 0.4, 0.6]])
    a = waypoint_mutation(one, 0.3, np.random.default_rng(3))
    b = gaussian_mutation(one, 0.3, np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)  # one waypoint: the paper's operator, draw for draw
    assert np.array_equal(genome, np.arange(15, dtype=float).reshape(5, 3)), "the input is not modified"


def test_remove_waypoint_deletes_one_row_drawn_uniformly():
    g = np.arange(12, dtype=np.float64).reshape(4, 3)
    removed = Counter()
    rng = np.random.default_rng(0)
    for _ in range(4000):
        child = remove_waypoint(g, rng)
        assert child.shape == (3, 3)
        # the child is g without exactly one of its rows, in the same order
        gone = [i for i in range(4) if np.array_equal(np.delete(g, i, axis=0), child)]
        assert len(gone) == 1
        removed[gone[0]] += 1
    assert set(removed) == {0, 1, 2, 3}
    assert all(abs(n / 4000 - 0.25) < 0.03 for n in removed.values())
    assert g.shape == (4, 3)  # input untouched


def test_remove_waypoint_keeps_a_one_waypoint_genome():
    g = np.array([[0.1, 0.2, 0.3]])
    child = remove_waypoint(g, np.random.default_rng(0))
    assert np.array_equal(child, g) and child is not g


def test_waypoint_mutation_redraws_a_rejected_waypoint_and_otherwise_draws_as_before():
    genome = np.full((4, 3), 0.5)
    plain = waypoint_mutation(genome, 0.3, np.random.default_rng(7))
    # redraws = 0, or no test: the draws of the operator without them, bit for bit
    np.testing.assert_array_equal(waypoint_mutation(genome, 0.3, np.random.default_rng(7), lambda p: False, 0), plain)
    np.testing.assert_array_equal(waypoint_mutation(genome, 0.3, np.random.default_rng(7), None, 5), plain)
    # a test accepting only moves that raise z: the same waypoint is drawn again until one does (within the bound)
    accepted = 0
    for seed in range(200):
        child = waypoint_mutation(genome, 0.3, np.random.default_rng(seed), lambda p: p[2] > 0.5, 10)
        changed = np.flatnonzero(np.any(child != genome, axis=1))
        assert len(changed) == 1, "still exactly one waypoint changes"
        accepted += child[changed[0], 2] > 0.5
    assert accepted == 200  # one in 2**11 would keep a rejected last draw: none in 200 here
    # nothing accepted: redraws + 1 draws are spent on one waypoint, and the last one stands
    rng, twin = np.random.default_rng(3), np.random.default_rng(3)
    child = waypoint_mutation(genome, 0.3, rng, lambda p: False, 4)
    row = int(twin.integers(4))
    noise = [twin.normal(0.0, 0.3, size=3) for _ in range(5)]
    np.testing.assert_array_equal(child[row], genome[row] + noise[-1])
    assert rng.random() == twin.random(), "exactly five noise draws were made"
