"""PRM* roadmap over callables: connection rule, incremental growth, edge ids, sampling (edges are
checked by the planner: lfd.planning.edgestore)."""

import math

import numpy as np
import pytest
import torch

from lfd.planning.roadmap import Roadmap, RoadmapSettings, ik_biased_samples, k_prm_star, mixed_samples
from helpers import box_world

BOX_LO, BOX_HI = np.array([-0.2, -0.6]), np.array([0.2, 0.6])


in_box, segment_hits_box = box_world(BOX_LO, BOX_HI)


def uniform(rng, d=2):
    return lambda n: rng.uniform(-1.0, 1.0, (n, d))


def free_roadmap(n, d=3, seed=0, **kw):
    rng = np.random.default_rng(seed)
    return Roadmap.build(uniform(rng, d), n, lambda q: False, lambda a, b: False, **kw)


def test_k_prm_star_formula_and_growth():
    for n, d in [(50, 2), (1000, 7), (5000, 7), (100, 3)]:
        assert k_prm_star(n, d) == math.ceil(math.e * (1 + 1 / d) * math.log(n))
    ks = [k_prm_star(n, 7) for n in (100, 1000, 5000, 10 ** 5)]
    assert ks == sorted(ks) and ks[0] < ks[-1]
    assert k_prm_star(1, 7) == 0 and k_prm_star(3, 7) == 2  # capped at n - 1


def test_build_connects_each_vertex_to_its_k_nearest():
    rm = free_roadmap(300)
    k = k_prm_star(300, 3)
    assert rm.n == 300 and rm.vertices.shape == (300, 3) and rm.k() == k
    V = rm.vertices
    for i in range(0, 300, 17):
        nearest = np.argsort(np.linalg.norm(V - V[i], axis=1))[1:k + 1]
        assert set(nearest.tolist()) <= set(rm.graph.adj[i])
    degrees = np.array([deg for _, deg in rm.graph.degree])
    assert degrees.min() >= k and rm.graph.number_of_edges() <= 300 * k


def test_add_vertices_grows_without_rebuilding():
    rm = free_roadmap(200, seed=1)
    old_edges = set(rm.graph.edges)
    k_old = rm.k()
    rng = np.random.default_rng(2)
    ids = rm.add_vertices(rng.uniform(-1, 1, (800, 3)))
    assert ids.tolist() == list(range(200, 1000)) and rm.n == 1000
    assert old_edges <= set(rm.graph.edges)
    k_new = rm.k()
    assert k_new > k_old
    V = rm.vertices
    for i in ids[::50]:
        nearest = np.argsort(np.linalg.norm(V - V[i], axis=1))[1:k_new + 1]
        assert set(nearest.tolist()) <= set(rm.graph.adj[int(i)])


def test_vertices_are_free_and_edges_are_left_to_the_planner():
    """The roadmap checks its vertices, never its edges (edge state belongs to lfd.planning.edgestore):
    building, growing and extra edges call no ``segment_fn`` and keep the edges the box cuts;
    ``segment_collides`` passes its ends to ``segment_fn`` and returns its answer, every call."""
    rng = np.random.default_rng(3)
    calls, answer = [], [True]

    def segment_fn(q1, q2):
        calls.append((np.array(q1), np.array(q2)))
        return answer[0]
    rm = Roadmap.build(uniform(rng), 250, in_box, segment_fn)
    ids = rm.add_vertices(rng.uniform(-1, 1, (30, 2)))
    rm.add_edges(np.stack([ids[:-1], ids[1:]], axis=1))
    assert not any(in_box(q) for q in rm.vertices)
    assert calls == [] and rm.counters["segment_checks"] == 0
    V = rm.vertices
    cut = [(u, w) for u, w in rm.graph.edges if segment_hits_box(V[u], V[w])]
    assert len(cut) > 10  # the box cuts edges, and they stay in the graph
    u, w = cut[0]
    assert rm.segment_collides(V[u], V[w]) is True
    answer[0] = False  # the answer is segment_fn's, not the roadmap's geometry
    assert rm.segment_collides(V[u], V[w]) is False
    assert len(calls) == 2 and rm.counters["segment_checks"] == 2  # asked again: not cached
    for q1, q2 in calls:
        np.testing.assert_array_equal(q1, V[u])
        np.testing.assert_array_equal(q2, V[w])


def test_edge_ids_index_the_edge_array():
    """``edge_array()[eid]`` are the ends of the graph's edge with that ``eid``: ids 0..E-1 in the
    order added, rows kept as the roadmap grows (new edges appended) and after extra edges."""
    rng = np.random.default_rng(4)
    rm = Roadmap.build(uniform(rng), 150, in_box, segment_hits_box)
    first = rm.edge_array().copy()
    assert len(first) == rm.n_edges == rm.graph.number_of_edges() > 0
    ids = rm.add_vertices(rng.uniform(-1, 1, (40, 2)))
    pairs = np.stack([ids[:-1], ids[1:]], axis=1)
    new = [[int(i), int(j)] for i, j in pairs if not rm.graph.has_edge(int(i), int(j))]
    n_before = rm.n_edges
    assert rm.add_edges(pairs) == len(new) > 0
    assert rm.add_edges(pairs) == 0  # already there: no new ids
    ends = rm.edge_array()
    assert len(ends) == rm.n_edges == rm.graph.number_of_edges() == n_before + len(new)
    assert ends[n_before:].tolist() == new  # the extra edges, in the order given
    np.testing.assert_array_equal(ends[:len(first)], first)
    eids = sorted(e for _, _, e in rm.graph.edges(data="eid"))
    assert eids == list(range(rm.n_edges))
    for u, w, e in rm.graph.edges(data="eid"):
        assert {int(ends[e, 0]), int(ends[e, 1])} == {u, w}
    with pytest.raises(ValueError):
        ends[0, 0] = 5  # read-only


def test_batch_collision_fn_is_used():
    rng = np.random.default_rng(5)
    calls = []

    def batch(Q):
        calls.append(len(Q))
        return np.array([in_box(q) for q in Q])

    rm = Roadmap.build(uniform(rng), 100, lambda q: pytest.fail("single check"), segment_hits_box,
                       batch_collision_fn=batch)
    assert rm.n == 100 and calls and not any(in_box(q) for q in rm.vertices)


@pytest.mark.parametrize("batched", [False, True])
def test_hits_pass_on_the_names_the_collision_callables_give(batched):
    """A callable may name what a configuration hits instead of answering True: ``hits`` passes
    the names on ("" where free) and ``in_collision`` reads them as booleans; a bare True or
    1 is ``UNNAMED``."""
    from lfd.planning.roadmap import UNNAMED

    def name(q):
        return "box" if in_box(q) else ("wall" if q[0] > 0.8 else "")

    rng = np.random.default_rng(8)
    Q = rng.uniform(-1, 1, (200, 2))
    want = [name(q) for q in Q]
    assert {"box", "wall", ""} <= set(want)
    if batched:
        named = Roadmap(2, None, segment_hits_box, batch_collision_fn=lambda Q: np.array([name(q) for q in Q]))
        bare = Roadmap(2, None, segment_hits_box, batch_collision_fn=lambda Q: np.array([int(bool(name(q))) for q in Q]))
    else:
        named, bare = Roadmap(2, name, segment_hits_box), Roadmap(2, lambda q: bool(name(q)), segment_hits_box)
    assert named.hits(Q).tolist() == want
    assert bare.hits(Q).tolist() == [UNNAMED if w else "" for w in want]
    assert named.in_collision(Q).tolist() == bare.in_collision(Q).tolist() == [bool(w) for w in want]
    assert named.hits(Q[:0]).shape == (0,)


def test_hits_reads_a_list_mixing_names_and_booleans():
    """A plain list of names, False and numpy booleans: nothing free is named "False"."""
    answers = ["box", False, 0, np.bool_(True), np.bool_(False), "", np.str_("wall"), True]
    rm = Roadmap(2, None, segment_hits_box, batch_collision_fn=lambda Q: list(answers[:len(Q)]))
    got = rm.hits(np.zeros((len(answers), 2)))
    assert got.tolist() == ["box", "", "", "?", "", "", "wall", "?"]


def _forgot_return(*q):
    hit = True  # noqa: F841 (the bug being tested: no return, so the answer is None)


@pytest.mark.parametrize("answer", [None, 0.5, 2, "distance", np.array([True, False]), [None]])
def test_an_answer_that_is_not_a_bool_or_a_name_is_refused_not_read_as_free(answer):
    """``None`` (a check that forgot its ``return``), a distance, a count or several values for
    one configuration: each a ValueError naming the callable; read as falsy, a forgotten return
    planned through every obstacle. ("distance" is a name: it stays a hit.)"""
    Q = np.zeros((1, 2))
    if isinstance(answer, str):
        assert Roadmap(2, lambda q: answer, segment_hits_box).hits(Q).tolist() == ["distance"]
        zero_d = Roadmap(2, lambda q: np.where(True, answer, ""), lambda a, b: np.where(False, answer, ""))
        assert zero_d.hits(Q).tolist() == ["distance"] and not zero_d.segment_collides(Q[0], Q[0] + 1)
        return
    single = Roadmap(2, lambda q: answer, lambda a, b: answer)
    with pytest.raises(ValueError, match="collision_fn"):
        single.hits(Q)
    with pytest.raises(ValueError, match="segment_fn"):
        single.segment_collides(Q[0], Q[0] + 1)
    batch = Roadmap(2, None, segment_hits_box, batch_collision_fn=lambda Q: [answer] * len(Q))
    with pytest.raises(ValueError, match="batch_collision_fn"):
        batch.hits(np.zeros((3, 2)))
    if isinstance(answer, (float, int)):  # the same as an array: (3,) of 0.5 or of 2
        array = Roadmap(2, None, segment_hits_box, batch_collision_fn=lambda Q: np.full(len(Q), answer))
        with pytest.raises(ValueError, match=r"batch_collision_fn must answer with bools \(or 0 and 1\) or names, "
                                             r"got dtype (float|int)64 \(a distance"):
            array.hits(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="returned None"):
        Roadmap(2, _forgot_return, segment_hits_box).hits(Q)
    with pytest.raises(ValueError, match="returned None"):
        Roadmap(2, None, segment_hits_box, batch_collision_fn=_forgot_return).hits(Q)


def test_torch_answers_read_like_numpy_ones():
    """A check written in torch: a 0-d bool tensor per configuration, or a (n,) tensor per batch."""
    Q = np.array([[0.0, 0.0], [0.9, 0.9]])  # the first inside the box
    want = in_box(Q[0]), in_box(Q[1])
    single = Roadmap(2, lambda q: torch.as_tensor(bool(in_box(q))), segment_hits_box)
    batch = Roadmap(2, None, segment_hits_box,
                    batch_collision_fn=lambda Q: torch.as_tensor([bool(in_box(q)) for q in Q]))
    assert single.in_collision(Q).tolist() == list(want) == batch.in_collision(Q).tolist() == [True, False]


def test_callables_cannot_change_the_roadmaps_configurations():
    """A check that writes into its argument (wrapping angles, say) moved the roadmap's vertices
    and the caller's array; it now gets a copy."""
    def wraps(q):
        q[..., 0] = 0.123
        return False

    Q = np.array([[0.5, 0.5], [0.6, 0.6]])
    rm = Roadmap(2, wraps, lambda a, b: wraps(a))
    assert rm.add_vertices(Q).tolist() == [0, 1]
    assert not rm.segment_collides(Q[0], Q[1])
    batch = Roadmap(2, None, lambda a, b: False, batch_collision_fn=lambda Q: wraps(Q) or [False] * len(Q))
    batch.add_vertices(Q)
    assert Q.tolist() == [[0.5, 0.5], [0.6, 0.6]] == rm.vertices.tolist() == batch.vertices.tolist()


def test_biased_samples_are_used_first_and_filtered():
    rng = np.random.default_rng(6)
    biased = np.array([[0.0, 0.0], [0.9, 0.9], [-0.9, 0.9]])  # the first is inside the box
    rm = Roadmap.build(uniform(rng), 50, in_box, segment_hits_box, biased_samples=biased)
    np.testing.assert_array_equal(rm.vertices[:2], biased[1:])


def test_mixed_samples_ratio():
    rng = np.random.default_rng(7)
    biased = np.full((100, 2), 5.0)
    Q = mixed_samples(uniform(rng), 200, biased, 0.25, rng)
    assert Q.shape == (200, 2) and int(np.sum(Q[:, 0] == 5.0)) == 50
    Q = mixed_samples(uniform(rng), 200, biased[:10], 0.5, rng)
    assert int(np.sum(Q[:, 0] == 5.0)) == 10  # fewer candidates than asked: all of them
    with pytest.raises(ValueError, match="bias_fraction"):
        mixed_samples(uniform(rng), 10, biased, 1.5, rng)


def test_ik_biased_samples_keeps_successes():
    targets = np.arange(4.0)[:, None]

    def ik_fn(x):
        return np.repeat(x, 3, axis=1), x[:, 0] % 2 == 0

    Q = ik_biased_samples(targets, ik_fn)
    np.testing.assert_array_equal(Q, [[0, 0, 0], [2, 2, 2]])


def test_errors_name_the_argument():
    rm = free_roadmap(20)
    with pytest.raises(ValueError, match="Q with shape"):
        rm.add_vertices(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="k_scale"):
        RoadmapSettings(k_scale=0)
    with pytest.raises(ValueError, match="n >= 1"):
        Roadmap.build(uniform(np.random.default_rng(0)), 0, in_box, segment_hits_box)


def test_a_collision_callable_answering_in_another_shape_is_refused_by_name():
    """A collision_fn answering per link (an array) raised numpy's 'truth value is ambiguous', a
    batch_collision_fn answering one bool numpy's 'cannot reshape'."""
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=r"must answer one configuration with a bool or a name, got ndarray of shape \(3,\)"):
        Roadmap.build(uniform(rng), 10, lambda q: np.zeros(3, dtype=bool), lambda a, b: False)
    with pytest.raises(ValueError, match=r"batch_collision_fn must answer each of the \d+ configurations, shape \(\d+,\); got shape \(\)"):
        Roadmap.build(uniform(rng), 10, lambda q: False, lambda a, b: False, batch_collision_fn=lambda Q: np.bool_(False))
    rm = Roadmap.build(uniform(rng), 10, lambda q: False, lambda a, b: False,
                       batch_collision_fn=lambda Q: np.zeros((len(Q), 1), dtype=bool))  # (B, 1) stays accepted
    assert rm.n == 10


def test_candidates_an_object_blocked_are_readmitted_when_it_leaves():
    """A box named "box" blocks part of the square while the roadmap is built: its candidates are
    set aside, not lost. Once it has moved, ``readmit("box")`` adds those now free (the
    vacated part is sampled again, like a fresh roadmap's) and keeps those it still hits aside;
    what hits the fixed "wall" or an unnamed obstacle is never readmitted."""
    place = {"box": np.array([0.0, 0.0])}

    def hits(q):
        if q[0] > 0.8:
            return "wall"
        return "box" if np.all(np.abs(q - place["box"]) <= 0.3) else ""

    rng = np.random.default_rng(3)
    rm = Roadmap.build(uniform(rng), 300, hits, lambda a, b: False)
    in_old = lambda V: np.all(np.abs(V) <= 0.3, axis=1)  # noqa: E731
    assert rm.n == 300 and not in_old(rm.vertices).any()
    aside = rm.n_set_aside
    assert aside > 20  # about 300 * 0.09 / 0.81 box candidates, and the wall's
    place["box"] = np.array([-0.5, -0.5])  # half over its old place, half beyond
    new = rm.readmit("box")
    V = rm.vertices[new]
    assert len(new) > 10 and in_old(V).all() and not np.any(np.all(np.abs(V - place["box"]) <= 0.3, axis=1))
    assert rm.readmit("wall").size == 0  # (it did not move: its candidates still hit it)
    assert rm.counters["readmitted"] == len(new)
    assert rm.readmit("box").size == 0  # (nothing moved since: those still hit stay aside)
    # every new vertex is joined to the roadmap like any other (k nearest)
    assert all(rm.graph.degree(int(v)) >= rm.k(rm.n) for v in new[:5])
    unnamed = Roadmap.build(uniform(np.random.default_rng(3)), 100, lambda q: bool(np.all(np.abs(q) <= 0.3)),
                            lambda a, b: False)
    assert unnamed.n_set_aside == 0
    # only what may move is kept (the wall never will), and a limit drops the surplus
    place["box"] = np.array([0.0, 0.0])
    only_box = Roadmap.build(uniform(np.random.default_rng(3)), 300, hits, lambda a, b: False, movable=["box"])
    assert 0 < only_box.n_set_aside < aside  # (the wall's candidates are not kept)
    place["box"] = np.array([5.0, 5.0])
    assert len(only_box.readmit("box", limit=4)) == 4 and only_box.n_set_aside == 0
