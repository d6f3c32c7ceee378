import numpy as np
import pytest

from babblegen import state_file
from babblegen.explorers import (
    EXPLORERS,
    NovEB,
    NovEBConfig,
    RandomBabbling,
    RandomWaypoints,
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
    """NovEB with the paper's 12 children per generation, and its genomes that only grow, unless told otherwise."""
    return make_explorer("noveb", {"children": 12, "remove_prob": 0.0, **cfg}, seed, PR2_LIMITS, START)


def test_registry_and_config_defaults():
    assert {"noveb": NovEB, "random": RandomBabbling, "random_waypoints": RandomWaypoints} == EXPLORERS
    cfg = NovEBConfig()
    assert (cfg.population, cfg.generations, cfg.k) == (12, 2000, 3)
    assert (cfg.mutation_prob, cfg.sigma, cfg.extend_prob, cfg.crossover_prob) == (0.3, 0.3, 0.05, 0.0)
    assert (cfg.children, cfg.lag) == (128, 0), "many children of few parents, generations not overlapping"
    ex = make_explorer("noveb", None, 0, PR2_LIMITS, START)
    tell_in_order(ex, ex.ask())
    gen1 = ex.ask()
    assert len(gen1) + len(ex._open[0].clones) == 128


@pytest.mark.parametrize(
    "bad",
    [
        {"population": 1},
        {"children": 0},
        {"lag": -1},
        {"lag": 0.5},
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
    assert not ex.can_ask, "generation 1 is bred from generation 0's survivors"
    with pytest.raises(RuntimeError):
        ex.ask()
    assert [[c.index for c in b] for b in ex.open_batches()] == [list(range(12))]
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
    ex = make_noveb(population=4, children=4, tie_break="oldest", archive_policy="most_novel", reuse_clones=False)
    gen0 = ex.ask()
    # codes 0b0, 0b1, 0b11 and one infeasible; k = 3 but only two neighbours exist:
    #   c0: 1, 2 -> 1.5    c1: 1, 1 -> 1.0    c2: 2, 1 -> 1.5 ; archive the most novel, tie -> c0
    evals = ex.tell(gen0, [np.array([v], np.uint64) for v in (0, 1, 3)] + [None])
    assert [e.novelty for e in evals] == [1.5, 1.0, 1.5, None]
    assert [e.archived for e in evals] == [True, False, False, False]
    assert ex.parents == [0, 2, 1]  # novelty order, ties to lower index

    gen1 = ex.ask()  # population 4, 4 children, indices 4..7
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
    (again,) = other.open_batches()
    assert [(c.index, c.parent, c.genome.tobytes()) for c in again] == [
        (c.index, c.parent, c.genome.tobytes()) for c in asked
    ]
    descs = [fake_descriptor(c.genome) for c in asked]
    assert [(e.novelty, e.archived) for e in other.tell(again, descs)] == [
        (e.novelty, e.archived) for e in ex.tell(asked, descs)
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
        ex = make_noveb(population=2, children=2, k=1, mutation_prob=1.0, tie_break=tie_break)
        zero = np.array([0], np.uint64)
        ex.tell(ex.ask(), [zero, zero])
        gen1 = ex.ask()
        assert [c.index for c in gen1] == [2, 3]
        ex.tell(gen1, [zero, zero])  # four individuals, all novelty 0
        assert ex.parents == survivors


def test_shortest_tie_break_keeps_fewer_waypoints_then_the_newest():
    ex = make_noveb(population=2, children=2, k=1, mutation_prob=0.0, extend_prob=1.0, tie_break="shortest")
    zero = np.array([0], np.uint64)
    ex.tell(ex.ask(), [zero, zero])  # two one-waypoint parents
    gen1 = ex.ask()
    assert [len(c.genome) for c in gen1] == [2, 2]  # extended children
    ex.tell(gen1, [zero, zero])  # four individuals, all novelty 0
    assert sorted(ex.parents) == [0, 1], "the one-waypoint parents survive"
    newest = make_noveb(population=2, children=2, k=1, mutation_prob=0.0, extend_prob=1.0, tie_break="newest")
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
    assert [[c.index for c in b] for b in ex.open_batches()] == [[0, 1, 2, 3, 4]]  # re-issued as it is
    ex.tell(cands, [fake_descriptor(c.genome) for c in cands])
    assert ex.ask()[0].index == 5


def test_max_waypoints_stops_extension():
    assert NovEBConfig().max_waypoints == 8 and NovEBConfig().remove_prob == 0.05  # the paper: unbounded, no removal
    assert NovEBConfig().remove_above == 4
    capped = make_noveb(extend_prob=1.0, max_waypoints=3, remove_prob=0.0)
    free = make_noveb(extend_prob=1.0, max_waypoints=None, remove_prob=0.0)
    lengths = {"capped": set(), "free": set()}
    for name, ex in (("capped", capped), ("free", free)):
        for _ in range(6):
            cands = ex.ask()
            lengths[name] |= {len(c.genome) for c in cands}
            ex.tell(cands, [fake_descriptor(c.genome) for c in cands])
    assert max(lengths["capped"]) == 3
    assert max(lengths["free"]) > 3


def test_remove_prob_shortens_genomes_and_is_off_in_the_papers_form():
    assert NovEBConfig(remove_prob=0.0).remove_prob == 0.0
    # grow first, then only remove: lengths fall back towards one waypoint
    ex = make_noveb(mutation_prob=0.0, extend_prob=1.0, tie_break="newest")
    for _ in range(6):
        tell_in_order(ex, ex.ask())
    assert max(len(g) for g in ex._parents) >= 3
    ex.config = NovEBConfig(**{**ex.config.__dict__, "extend_prob": 0.0, "remove_prob": 1.0, "remove_above": 1})
    cands = ex.ask()
    # every child of a parent with n > 1 waypoints has n - 1 (the parent's genome minus one row)
    for c in cands:
        parent = ex._parents[[int(i) for i in ex._parent_index].index(c.parent)]
        assert len(c.genome) == max(len(parent) - 1, 1)


def test_remove_above_keeps_short_genomes_whole():
    ex = make_noveb(mutation_prob=0.0, extend_prob=1.0, tie_break="newest")
    for _ in range(6):
        tell_in_order(ex, ex.ask())
    lengths = sorted(len(g) for g in ex._parents)
    assert lengths[0] < lengths[-1] and lengths[-1] >= 4
    limit = (lengths[0] + lengths[-1]) // 2
    ex.config = NovEBConfig(**{**ex.config.__dict__, "extend_prob": 0.0, "remove_prob": 1.0, "remove_above": limit})
    cands = ex.ask()
    for c in cands:
        parent = ex._parents[[int(i) for i in ex._parent_index].index(c.parent)]
        assert len(c.genome) == (len(parent) - 1 if len(parent) > limit else len(parent))


@pytest.mark.parametrize(
    "bad", [{"extend_prob": 0.6, "remove_prob": 0.5}, {"max_waypoints": -1}, {"remove_above": 0}, {"remove_above": 2.5}]
)
def test_bad_length_settings_are_refused(bad):
    with pytest.raises(ValueError):
        NovEBConfig(**bad)


def test_max_waypoints_zero_means_no_bound():
    assert NovEBConfig(max_waypoints=0).max_waypoints is None


def tell_in_order(explorer, batch):
    return explorer.tell(batch, [fake_descriptor(c.genome) for c in batch])


def test_lag_breeds_a_generation_from_the_survivors_of_the_one_lag_plus_one_before():
    ex = make_noveb(3, children=6, lag=1)
    gen0 = ex.ask()
    assert not ex.can_ask, "nothing to breed from before generation 0 is told"
    tell_in_order(ex, gen0)
    parents0 = set(ex.parents)
    gen1, gen2 = ex.ask(), ex.ask()
    assert not ex.can_ask, "lag 1: two generations open at most"
    assert {c.generation for c in gen1} == {1} and {c.generation for c in gen2} == {2}
    assert {c.parent for c in gen1 + gen2} <= parents0, "both bred from generation 0's survivors"
    assert [c.index for c in gen1 + gen2] == list(range(12, 12 + len(gen1) + len(gen2)))
    with pytest.raises(ValueError):
        tell_in_order(ex, gen2)  # batches are told in the order asked
    tell_in_order(ex, gen1)
    parents1 = set(ex.parents)
    gen3 = ex.ask()
    assert {c.parent for c in gen3} <= parents1, "generation 3 is bred from generation 1's survivors"
    assert [b[0].generation for b in ex.open_batches() if b] == [2, 3]
    tell_in_order(ex, gen2)
    assert ex.generation == 3


def test_a_child_repeating_a_genome_still_in_flight_reuses_its_outcome_when_told():
    # one-waypoint parents, every child extended and not mutated: a parent has one possible child (the midpoint
    # inserted), so generations 1 and 2, both bred from generation 0's survivors, propose the same genomes
    ex = make_noveb(4, children=12, lag=1, mutation_prob=0.0, extend_prob=1.0)
    tell_in_order(ex, ex.ask())
    gen1, gen2 = ex.ask(), ex.ask()
    (clones,) = [b.clones for b in ex._open[1:]]
    in_flight = {c.index: c for c in gen1}
    assert len([c for c in clones if c.source in in_flight]) >= 6, "generation 2 repeats generation 1's genomes"
    assert all(c.source in in_flight or c.source >= 12 + len(gen1) for c in clones)
    tell_in_order(ex, gen1)
    tell_in_order(ex, gen2)
    assert ex.last_clones == clones
    source = {**in_flight, **{c.index: c for c in gen2}}
    for clone in clones:
        np.testing.assert_array_equal(clone.genome, source[clone.source].genome)
        feasible = fake_descriptor(clone.genome) is not None
        assert (clone.novelty is not None) == feasible, "it reuses its source's outcome, told by now"
    assert ex._in_flight == {} and ex.open_batches() == []


def test_state_with_two_open_batches_continues_identically():
    ex = make_noveb(5, children=8, lag=1, extend_prob=0.3)
    tell_in_order(ex, ex.ask())
    ex.ask()
    for _ in range(3):
        ex.ask()
        tell_in_order(ex, ex.open_batches()[0])
    ex.ask()
    assert len(ex.open_batches()) == 2
    state = state_file.loads(state_file.dumps(ex.state_dict()))
    other = make_noveb(0, children=8, lag=1)
    other.load_state_dict(state)

    def drive(explorer, rounds):
        seen = []
        for _ in range(rounds):
            batch = explorer.open_batches()[0]
            evals = tell_in_order(explorer, batch)
            seen.append(
                [(c.index, c.genome.tobytes(), e.novelty, e.archived) for c, e in zip(batch, evals, strict=True)]
            )
            seen.append([(c.source, c.novelty, c.survived) for c in explorer.last_clones])
            explorer.ask()
        return seen

    assert drive(other, 5) == drive(ex, 5)
    assert other.parents == ex.parents


def test_a_state_stored_by_the_generational_version_loads_with_the_same_meaning():
    """Checkpoints made before generations could overlap held one batch (``pending``, ``asked``) and the number
    of children as ``keep_fraction``; such a run resumes as the same search."""
    ex = make_noveb(5, population=6, children=6)
    run_rounds(ex, 2)
    asked = ex.ask()
    state = state_file.loads(state_file.dumps(ex.state_dict()))
    old = {k: v for k, v in state.items() if k != "open"}
    (batch,) = state["open"]
    old.update(pending=batch["candidates"], pending_clones=batch["clones"], asked=True)
    old["config"] = {k: v for k, v in state["config"].items() if k not in ("children", "lag")}
    old["config"]["keep_fraction"] = 0.5
    other = make_noveb(0)
    other.load_state_dict(old)
    assert (other.config.population, other.config.children, other.config.lag) == (6, 6, 0)
    (again,) = other.open_batches()
    assert [c.genome.tobytes() for c in again] == [c.genome.tobytes() for c in asked]
    tell_in_order(other, again)
    tell_in_order(ex, asked)
    assert run_rounds(other, 3) == run_rounds(ex, 3)


def test_ask_while_possible_opens_what_the_lag_allows_within_the_attempts_and_generations():
    from babblegen.explorers.base import ask_while_possible

    ex = make_noveb(2, children=6, lag=2, generations=4)
    assert len(ask_while_possible(ex, None, 4)) == 1  # generation 0 alone
    tell_in_order(ex, ex.open_batches()[0])
    assert len(ask_while_possible(ex, None, 4)) == 3  # generations 1, 2 and 3: the last there is
    tell_in_order(ex, ex.open_batches()[0])
    assert ask_while_possible(ex, None, 4) == []
    capped = make_noveb(2, children=6, lag=2)
    tell_in_order(capped, ask_while_possible(capped, 14, 2000)[0])
    batches = ask_while_possible(capped, 14, 2000)
    assert sum(len(b) for b in batches) == 2 and capped.attempts_asked == 14


def test_reach_redraws_spend_no_attempt_on_a_mutated_waypoint_out_of_reach():
    """The fake world refuses final points with x > 0.8; told that, NovEB redraws such mutations instead of
    proposing them, and draws as the paper does without it."""
    assert NovEBConfig().reach_redraws == 0  # the paper's mutation by default

    def in_reach(point: np.ndarray) -> bool:
        return bool(point[0] <= 0.8)

    refused = {}
    for redraws in (0, 10):
        ex = make_explorer(
            "noveb",
            {"children": 48, "remove_prob": 0.0, "mutation_prob": 1.0, "extend_prob": 0.0, "reach_redraws": redraws},
            3,
            PR2_LIMITS,
            START,
            in_reach=in_reach,
        )
        tell_in_order(ex, ex.ask())  # the first generation: random genomes, not mutations
        children = []
        for _ in range(4):
            cands = ex.ask()
            children += cands
            tell_in_order(ex, cands)
        refused[redraws] = sum(fake_descriptor(c.genome) is None for c in children) / len(children)
    assert refused[0] > 0.1 and refused[10] < 0.01, refused
    with pytest.raises(ValueError, match="in_reach"):
        make_explorer("noveb", {"reach_redraws": 3}, 0, PR2_LIMITS, START)
    with pytest.raises(ValueError):
        NovEBConfig(reach_redraws=-1)


def test_independent_share_draws_children_as_random_waypoints_does():
    """A share of 0 breeds exactly as before; a share of 1 draws every child independently: no parent, 1 to 4
    waypoints uniform in the workspace box; with varied starts each from a new start."""
    plain, zero = make_noveb(seed=3), make_noveb(seed=3, independent_share=0.0)
    assert run_rounds(plain, 4) == run_rounds(zero, 4)
    ex = make_noveb(seed=3, independent_share=1.0, children=200)
    tell_in_order(ex, ex.ask())
    children = ex.ask()
    assert children and all(c.parent is None for c in children)
    lengths = [len(c.genome) for c in children]
    assert set(lengths) == {1, 2, 3, 4}
    assert all(((c.genome >= 0) & (c.genome < 1)).all() for c in children)
    half = make_noveb(seed=3, independent_share=0.25, children=400)
    tell_in_order(half, half.ask())
    independent = sum(c.parent is None for c in half.ask())
    assert 70 < independent < 130  # about a quarter of the 400 children (bred ones may be clones, never asked)
    with pytest.raises(ValueError, match="independent_share"):
        NovEBConfig(independent_share=1.5)
