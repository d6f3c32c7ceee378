import numpy as np
import pytest

from babblegen import state_file
from babblegen.explorers import (
    EXPLORERS,
    NovEB,
    NovEBConfig,
    RandomBabbling,
    make_explorer,
)
from babblegen.explorers.base import Candidate

START = np.array([0.5, 0.0, 0.5])
PI = np.pi
PR2_LIMITS = np.array([[-2.1, 0.6], [-0.4, 1.3], [-3.9, 0.8], [-2.3, 0.0], [-PI, PI], [-2.0, 0.0], [-PI, PI]])


def fake_descriptor(genome: np.ndarray) -> np.ndarray | None:
    """Deterministic stand-in for the world: thermometer code of the quantised final point.

    Each coordinate clipped to [0, 1] becomes q in 0..16 ones in its own 16-bit field, so Hamming distance is
    the L1 distance of the quantised final points. Final points with x > 0.8 are "unreachable".
    """
    p = genome[-1]
    if p[0] > 0.8:
        return None
    q = np.floor(np.clip(p, 0.0, 1.0) * 16).astype(int)
    value = sum(((1 << int(qc)) - 1) << (16 * c) for c, qc in enumerate(q))
    return np.array([value], dtype=np.uint64)


def run_rounds(explorer, rounds: int):
    history = []
    for _ in range(rounds):
        cands = explorer.ask()
        descs = [fake_descriptor(c.genome) if c.kind == "ee_waypoints" else None for c in cands]
        evals = explorer.tell(cands, descs)
        history.append(
            [
                (c.index, c.generation, c.parent, c.genome.tobytes(), e.novelty, e.archived)
                for c, e in zip(cands, evals, strict=True)
            ]
        )
    return history


def make_noveb(seed: int = 7, **cfg) -> NovEB:
    return make_explorer("noveb", cfg or None, seed, PR2_LIMITS, START)


def test_registry_and_config_defaults():
    assert {"noveb": NovEB, "random": RandomBabbling} == EXPLORERS
    cfg = NovEBConfig()
    assert (cfg.population, cfg.generations, cfg.k, cfg.keep_fraction) == (12, 2000, 3, 0.5)
    assert (cfg.mutation_prob, cfg.sigma, cfg.extend_prob, cfg.crossover_prob) == (0.3, 0.3, 0.05, 0.0)
    assert cfg.n_children == 12
    assert NovEBConfig(population=10, keep_fraction=0.25).n_children == 30


@pytest.mark.parametrize(
    "bad",
    [
        {"population": 1},
        {"keep_fraction": 1.0},
        {"keep_fraction": 0.0},
        {"mutation_prob": 1.5},
        {"k": 0},
        {"sigma": -0.1},
        {"populaton": 12},
    ],
)
def test_config_validation(bad):
    with pytest.raises(ValueError):
        make_noveb(**bad)


def test_make_explorer_errors():
    with pytest.raises(ValueError):
        make_explorer("nope", None, 0, PR2_LIMITS, START)
    with pytest.raises(ValueError):
        make_explorer("noveb", None, 0, PR2_LIMITS, None)
    with pytest.raises(ValueError):
        make_explorer("random", None, 0, None, START)


def test_generation_flow_indices_and_parents():
    ex = make_noveb()
    gen0 = ex.ask()
    assert len(gen0) == 12
    assert [c.index for c in gen0] == list(range(12))
    assert all(c.parent is None and c.generation == 0 and c.genome.shape == (1, 3) for c in gen0)
    assert all(((c.genome >= 0) & (c.genome < 1)).all() for c in gen0)
    assert [c.index for c in ex.ask()] == list(range(12))  # ask is idempotent until tell
    evals = ex.tell(gen0, [fake_descriptor(c.genome) for c in gen0])
    feasible = {c.index for c in gen0 if fake_descriptor(c.genome) is not None}
    assert set(ex.parents) == feasible  # fewer feasible than the population: all kept
    assert ex.archive_size == 1 and sum(e.archived for e in evals) == 1

    gen1 = ex.ask()
    assert [c.index for c in gen1] == list(range(12, 12 + len(gen1)))  # clones take no attempt index
    assert all(c.generation == 1 and c.parent in feasible for c in gen1)
    ex.tell(gen1, [fake_descriptor(c.genome) for c in gen1])
    assert len(gen1) + len(ex.last_clones) == 12  # 12 children: evaluated or reusing an outcome
    assert ex.generation == 2 and len(ex.parents) <= 12
    assert not ex.done
    short = make_noveb(generations=2)
    run_rounds(short, 2)
    assert short.done


def test_novelty_archive_and_selection_by_hand():
    # the paper's literal procedure: every child evaluated, most novel archived, ties to the older
    ex = make_noveb(population=4, tie_break="oldest", archive_policy="most_novel", reuse_clones=False)
    gen0 = ex.ask()
    # codes 0b0, 0b1, 0b11 and one infeasible; k = 3 but only two neighbours exist:
    #   c0: 1, 2 -> 1.5    c1: 1, 1 -> 1.0    c2: 2, 1 -> 1.5 ; archive the most novel, tie -> c0
    evals = ex.tell(gen0, [np.array([v], np.uint64) for v in (0, 1, 3)] + [None])
    assert [e.novelty for e in evals] == [1.5, 1.0, 1.5, None]
    assert [e.archived for e in evals] == [True, False, False, False]
    assert ex.parents == [0, 2, 1]  # novelty order, ties to lower index

    gen1 = ex.ask()  # population 4, keep 50 % -> 4 children, indices 4..7
    assert [c.index for c in gen1] == [4, 5, 6, 7]
    # pool = parents (codes 0, 3, 1) + children (15, 0, infeasible, 7), archive = {0}.
    # Distances to the others in the pool, then to the archive; k = 3 smallest:
    #   P 0:  3->2 1->1 15->4 0->0 7->3 | 0  -> 0 0 1 = 1/3
    #   P 3:  0->2 1->1 15->2 0->2 7->1 | 2  -> 1 1 2 = 4/3
    #   P 1:  0->1 3->1 15->3 0->1 7->2 | 1  -> 1 1 1 = 1
    #   C 15: 0->4 3->2 1->3 0->4 7->1 | 4  -> 1 2 3 = 2
    #   C 0:  0->0 3->2 1->1 15->4 7->3 | 0  -> 0 0 1 = 1/3
    #   C 7:  0->3 3->1 1->2 15->1 0->3 | 3  -> 1 1 2 = 4/3
    evals = ex.tell(gen1, [np.array([15], np.uint64), np.array([0], np.uint64), None, np.array([7], np.uint64)])
    np.testing.assert_allclose([e.novelty for e in evals if e.novelty is not None], [2.0, 1 / 3, 4 / 3])
    assert evals[2].novelty is None
    assert [e.archived for e in evals] == [True, False, False, False]
    assert ex.archive_size == 2
    np.testing.assert_array_equal(ex.archive.descriptors[:, 0], [0, 15])
    assert [m["index"] for m in ex.archive.meta] == [0, 4]
    # survivors: 2 (child 4), 4/3 (parent 2, then child 7), 1 (parent 1)
    assert ex.parents == [4, 2, 7, 1]


def test_infeasible_never_archived_nor_parents():
    ex = make_noveb(seed=3)
    infeasible: set[int] = set()
    for _ in range(30):
        cands = ex.ask()
        descs = [fake_descriptor(c.genome) for c in cands]
        evals = ex.tell(cands, descs)
        for c, d, e in zip(cands, descs, evals, strict=True):
            if d is None:
                infeasible.add(c.index)
                assert e.novelty is None and not e.archived
            else:
                assert e.novelty is not None and e.novelty >= 0
        assert not infeasible & set(ex.parents)
        assert not infeasible & {m["index"] for m in ex.archive.meta}
    assert infeasible  # the test exercised the infeasible path
    assert ex.archive_size == 30


def test_all_infeasible_first_generation_draws_random_again():
    ex = make_noveb()
    gen0 = ex.ask()
    evals = ex.tell(gen0, [None] * len(gen0))
    assert all(e.novelty is None and not e.archived for e in evals)
    assert ex.archive_size == 0 and ex.parents == []
    again = ex.ask()
    assert len(again) == 12 and all(c.parent is None and c.genome.shape == (1, 3) for c in again)
    assert again[0].index == 12 and again[0].generation == 1


def test_children_without_variation_are_copies_and_extension_adds_midpoints():
    ex = make_noveb(mutation_prob=0.0, extend_prob=0.0)
    run_rounds(ex, 1)
    parents = {i: g.copy() for i, g in zip(ex.parents, ex._parents, strict=True)}
    for c in ex.ask():
        np.testing.assert_array_equal(c.genome, parents[c.parent])

    ex = make_noveb(mutation_prob=0.0, extend_prob=1.0)
    run_rounds(ex, 1)
    parents = {i: g.copy() for i, g in zip(ex.parents, ex._parents, strict=True)}
    for c in ex.ask():
        p = parents[c.parent]  # one waypoint: the new point is midway between START and it
        np.testing.assert_allclose(c.genome, np.vstack([(START + p[0]) / 2, p]))


def test_same_seed_same_run_and_different_seed_differs():
    cfg = {"extend_prob": 0.3, "crossover_prob": 0.5}
    a = run_rounds(make_noveb(11, **cfg), 8)
    b = run_rounds(make_noveb(11, **cfg), 8)
    c = run_rounds(make_noveb(12, **cfg), 8)
    assert a == b
    assert a != c
    assert any(len(row[3]) > 24 for gen in a for row in gen)  # some genomes were extended


def test_state_dict_round_trip_continues_identically():
    ex = make_noveb(5, extend_prob=0.3)
    run_rounds(ex, 4)
    state = state_file.loads(state_file.dumps(ex.state_dict()))
    expected = run_rounds(ex, 4)
    other = make_noveb(999)  # different seed: everything must come from the state
    other.load_state_dict(state)
    assert run_rounds(other, 4) == expected
    np.testing.assert_array_equal(other.archive.descriptors, ex.archive.descriptors)
    assert other.parents == ex.parents


def test_state_between_ask_and_tell_reissues_the_batch():
    ex = make_noveb(5)
    run_rounds(ex, 2)
    asked = ex.ask()
    state = state_file.loads(state_file.dumps(ex.state_dict()))
    other = make_noveb(0)
    other.load_state_dict(state)
    again = other.ask()
    assert [(c.index, c.parent, c.genome.tobytes()) for c in again] == [
        (c.index, c.parent, c.genome.tobytes()) for c in asked
    ]
    assert run_rounds(other, 3) == run_rounds(ex, 3)


def test_tell_rejects_other_candidates():
    ex = make_noveb()
    cands = ex.ask()
    with pytest.raises(ValueError):
        ex.tell(cands[:-1], [None] * 11)
    wrong = [Candidate(c.index + 100, 0, c.kind, c.genome, None) for c in cands]
    with pytest.raises(ValueError):
        ex.tell(wrong, [None] * 12)
    with pytest.raises(RuntimeError):
        make_noveb().tell([], [])


def test_random_babbling_within_limits_and_reproducible():
    rb = make_explorer("random", {"population": 50}, 3, PR2_LIMITS, START)
    targets = []
    for g in range(20):
        cands = rb.ask()
        assert len(cands) == 50
        assert all(c.kind == "joint_target" and c.parent is None and c.generation == g for c in cands)
        rb.tell(cands, [None] * len(cands))
        targets.extend(c.genome for c in cands)
    t = np.stack(targets)
    assert t.shape == (1000, 7)
    assert np.all(t >= PR2_LIMITS[:, 0]) and np.all(t <= PR2_LIMITS[:, 1])
    # uniform: each joint's mean is near the middle of its range (std of the mean ~ range * 0.0091)
    span = PR2_LIMITS[:, 1] - PR2_LIMITS[:, 0]
    assert np.all(np.abs(t.mean(0) - PR2_LIMITS.mean(1)) < 0.04 * span)
    assert np.all(t.min(0) < PR2_LIMITS[:, 0] + 0.01 * span) and np.all(t.max(0) > PR2_LIMITS[:, 1] - 0.01 * span)

    again = make_explorer("random", {"population": 50}, 3, PR2_LIMITS, START)
    np.testing.assert_array_equal(np.stack([c.genome for c in again.ask()]), t[:50])


def test_random_babbling_novelty_and_state():
    rb = RandomBabbling({"population": 3}, 0, joint_limits=PR2_LIMITS)
    cands = rb.ask()
    # codes 0 and 1, one infeasible: each has one neighbour at distance 1; the first is archived
    evals = rb.tell(cands, [np.array([0], np.uint64), None, np.array([1], np.uint64)])
    assert [(e.novelty, e.archived) for e in evals] == [(1.0, True), (None, False), (1.0, False)]
    assert rb.archive_size == 1
    state = state_file.loads(state_file.dumps(rb.state_dict()))
    expected = rb.ask()
    other = RandomBabbling({"population": 3}, 42, joint_limits=PR2_LIMITS)
    other.load_state_dict(state)
    got = other.ask()
    assert [c.index for c in got] == [3, 4, 5]
    np.testing.assert_array_equal(np.stack([c.genome for c in got]), np.stack([c.genome for c in expected]))
    with pytest.raises(ValueError):
        other.load_state_dict(make_noveb().state_dict())


def test_clones_reuse_the_outcome_and_take_no_attempt():
    ex = make_noveb(mutation_prob=0.0, extend_prob=0.0)  # every child is a copy of its parent
    gen0 = ex.ask()
    ex.tell(gen0, [fake_descriptor(c.genome) for c in gen0])
    codes = {c.index: fake_descriptor(c.genome) for c in gen0}
    assert ex.ask() == []  # nothing to simulate
    ex.tell([], [])
    clones = ex.last_clones
    assert len(clones) == 12 and ex.generation == 2
    assert all(c.source == c.parent and c.source in codes and c.generation == 1 for c in clones)
    assert all(c.novelty is not None for c in clones)  # the search sees them, with the parent's descriptor
    assert ex.archive_size == 1  # a clone's descriptor is not new: nothing archived
    ex.config.mutation_prob = 1.0
    assert ex.ask()[0].index == 12  # the next real attempt continues the numbering

    literal = make_noveb(mutation_prob=0.0, extend_prob=0.0, reuse_clones=False)
    run_rounds(literal, 1)
    again = literal.ask()
    assert len(again) == 12 and [c.index for c in again] == list(range(12, 24))


def test_identical_children_of_one_batch_are_simulated_once():
    ex = make_noveb(mutation_prob=0.0, extend_prob=1.0)  # one-waypoint parent + extension: one possible child
    run_rounds(ex, 1)
    cands = ex.ask()
    keys = {c.genome.tobytes() for c in cands}
    assert len(keys) == len(cands)  # no genome asked twice
    ex.tell(cands, [fake_descriptor(c.genome) for c in cands])
    by_index = {c.index: c for c in cands}
    assert ex.last_clones and len(cands) + len(ex.last_clones) == 12
    for clone in ex.last_clones:
        np.testing.assert_array_equal(clone.genome, by_index[clone.source].genome)


def test_ties_go_to_the_newest_or_the_oldest_as_configured():
    for tie_break, survivors in (("newest", [3, 2]), ("oldest", [0, 1])):
        ex = make_noveb(population=2, k=1, mutation_prob=1.0, tie_break=tie_break)
        zero = np.array([0], np.uint64)
        ex.tell(ex.ask(), [zero, zero])
        gen1 = ex.ask()
        assert [c.index for c in gen1] == [2, 3]
        ex.tell(gen1, [zero, zero])  # four individuals, all novelty 0
        assert ex.parents == survivors


def test_shortest_tie_break_keeps_fewer_waypoints_then_the_newest():
    ex = make_noveb(population=2, k=1, mutation_prob=0.0, extend_prob=1.0, tie_break="shortest")
    zero = np.array([0], np.uint64)
    ex.tell(ex.ask(), [zero, zero])  # two one-waypoint parents
    gen1 = ex.ask()
    assert [len(c.genome) for c in gen1] == [2, 2]  # extended children
    ex.tell(gen1, [zero, zero])  # four individuals, all novelty 0
    assert sorted(ex.parents) == [0, 1], "the one-waypoint parents survive"
    newest = make_noveb(population=2, k=1, mutation_prob=0.0, extend_prob=1.0, tie_break="newest")
    newest.tell(newest.ask(), [zero, zero])
    newest.tell(newest.ask(), [zero, zero])
    assert newest.parents == [3, 2], "without parsimony the longer children win the ties"


def test_archive_takes_only_descriptors_it_does_not_hold():
    from babblegen.novelty import Archive, MostNovelUnseen

    archive = Archive()
    archive.add(np.array([5], np.uint64))
    codes = np.array([[5], [1], [1], [6]], np.uint64)
    nov = np.array([3.0, 2.0, 2.0, 1.0])
    assert MostNovelUnseen(1).select(nov, codes, archive).tolist() == [1]
    assert MostNovelUnseen(3).select(nov, codes, archive).tolist() == [1, 3]


def test_max_new_caps_a_batch():
    ex = make_noveb()
    cands = ex.ask(max_new=5)
    assert [c.index for c in cands] == [0, 1, 2, 3, 4]
    assert [c.index for c in ex.ask(max_new=1)] == [0, 1, 2, 3, 4]  # the open batch is re-issued as it is
    ex.tell(cands, [fake_descriptor(c.genome) for c in cands])
    assert ex.ask()[0].index == 5


def test_max_waypoints_stops_extension_and_is_off_by_default():
    assert NovEBConfig().max_waypoints is None  # the paper: genomes grow without bound
    capped = make_noveb(extend_prob=1.0, max_waypoints=3)
    free = make_noveb(extend_prob=1.0)
    lengths = {"capped": set(), "free": set()}
    for name, ex in (("capped", capped), ("free", free)):
        for _ in range(6):
            cands = ex.ask()
            lengths[name] |= {len(c.genome) for c in cands}
            ex.tell(cands, [fake_descriptor(c.genome) for c in cands])
    assert max(lengths["capped"]) == 3
    assert max(lengths["free"]) > 3
