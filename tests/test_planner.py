"""Spatiotemporal planning: A* with the exact cost-to-go and Lazy PRM path checks against plain
networkx Dijkstra on a fully evaluated, eagerly collision-checked product graph built here
independently; re-planning after landmark moves and after an obstacle moved (``invalidate``);
statuses; the edge integral; the batched costs against costs computed edge by edge."""

import math

import networkx as nx
import numpy as np
import pytest
import torch

from lfd.planning.edgestore import BLOCKED, FREE, UNKNOWN, EdgeStore
from lfd.planning.planner import ClosedLoopPlanner, PlannerSettings, time_step
from lfd.planning.roadmap import Roadmap, k_prm_star
from lfd.planning.stepcost import CallableStepCost
from lfd.planning.stsearch import SearchGraph, cost_to_go, transition_table
from helpers import box_world

# ---------------------------------------------------------------- toy world (d = 2)
BOX_LO, BOX_HI = np.array([0.15, 0.35]), np.array([0.45, 0.9])  # cuts the arc of the means
DT, T2 = 0.1, 8
VMAX2 = np.array([1.0, 2.0])
SIGMA = 0.15
FLOOR = 2 * math.log(math.sqrt(2 * math.pi) * SIGMA)  # the Gaussian nll's minimum (d = 2)

in_box, segment_hits_box = box_world(BOX_LO, BOX_HI)


def arc_means(T, shift=0.0):
    th = np.linspace(np.pi, 0.0, T) + shift
    return np.stack([0.7 * np.cos(th), 0.7 * np.sin(th)], axis=1)  # (T, 2)


def gaussian_factory(sigma=SIGMA):
    """landmarks = the per-step means (T, d); step_nll = Gaussian nll (negative near the means)."""
    def factory(landmarks):
        mu = torch.as_tensor(np.asarray(landmarks, dtype=float))
        const = mu.shape[1] * math.log(math.sqrt(2 * math.pi) * sigma)

        def step_nll(Q):
            return 0.5 * ((Q[:, None, :] - mu[None]) ** 2).sum(-1) / sigma ** 2 + const
        return step_nll
    return factory


def step_cost(T, sigma=SIGMA, d=2):
    return CallableStepCost(gaussian_factory(sigma), T, floor=d * math.log(math.sqrt(2 * math.pi) * sigma))


def trans_table(T, p=(0.3, 0.5, 0.2)):
    return -np.log(np.tile(np.asarray(p), (T, 1)))  # (T, 3) costs of offsets 0, 1, 2


@pytest.fixture(scope="module")
def toy():
    rng = np.random.default_rng(0)
    return Roadmap.build(lambda n: rng.uniform(-1.0, 1.0, (n, 2)), 180, in_box, segment_hits_box)


# ---------------------------------------------------------------- independent reference
def reference_graph(rm, step_nll, trans, dt, vmax, q_start, floor, quad_dt=None, q_goal=None,
                    seg=segment_hits_box):
    """The fully evaluated, eagerly collision-checked product graph, nodes ((v | "s" | "g"), t)."""
    T = trans.shape[0]
    quad_dt = quad_dt or dt
    V = np.array(rm.vertices)
    n = len(V)
    ell = lambda Q: step_nll(torch.as_tensor(Q)).numpy() - floor  # noqa: E731
    pos = {v: V[v] for v in range(n)}
    pos["s"] = q_start
    k = k_prm_star(n + 1, V.shape[1])
    edges = [(u, w) for u, w in rm.graph.edges if not seg(V[u], V[w])]
    nearest = lambda q: np.argsort(np.linalg.norm(V - q, axis=1), kind="stable")[:k]  # noqa: E731
    edges += [("s", int(j)) for j in nearest(q_start) if not seg(q_start, V[j])]
    if q_goal is not None:
        pos["g"] = q_goal
        edges += [("g", int(j)) for j in nearest(q_goal) if not seg(q_goal, V[j])]
        if not seg(q_start, q_goal):
            edges.append(("s", "g"))
    G = nx.DiGraph()
    for u, w in edges:  # "s" (the robot) is a source, "g" (the goal) a sink
        if u == "g" or (u == "s" and w == "g"):
            u, w = w, u
        a, b = pos[u], pos[w]
        tau = np.max(np.abs(b - a) / vmax)
        m = max(1, math.ceil(tau / quad_dt - 1e-9))
        vals = ell(a + (b - a) * np.linspace(0, 1, m + 1)[:, None])  # (m + 1, T)
        mean = (vals[0] / 2 + vals[1:-1].sum(0) + vals[-1] / 2) / m
        for t in range(T):
            c = tau / dt * (trans[t, 0] + mean[t])
            if math.isnan(c):
                c = math.inf
            if c < math.inf:
                G.add_edge((u, t), (w, t), weight=c)
                if u != "s" and w != "g":
                    G.add_edge((w, t), (u, t), weight=c)
    for v, q in pos.items():
        lq = ell(q[None])[0]
        for t in range(T):
            for k_ in range(1, trans.shape[1]):
                if t + k_ < T and trans[t, k_] < math.inf:
                    G.add_edge((v, t), (v, t + k_), weight=trans[t, k_] + lq[t + k_])
        G.add_edge((v, T - 1), "sink", weight=0.0)
    return G


def reference_cost(rm, means, trans, q_start, t_start, q_goal=None, sigma=SIGMA, d=2, vmax=VMAX2, **kw):
    """Plain nx.dijkstra on the fully evaluated product graph."""
    floor = d * math.log(math.sqrt(2 * math.pi) * sigma)
    G = reference_graph(rm, gaussian_factory(sigma)(means), trans, DT, vmax, q_start, floor, q_goal=q_goal, **kw)
    target = "sink" if q_goal is None else ("g", trans.shape[0] - 1)
    try:
        return nx.dijkstra_path_length(G, ("s", t_start), target)
    except (nx.NetworkXNoPath, nx.NodeNotFound):
        return math.inf


def make_planner(rm, means, trans=None, **settings):
    T = len(means)
    p = ClosedLoopPlanner(rm, step_cost(T), trans_table(T) if trans is None else trans, DT, VMAX2,
                          settings=PlannerSettings(**settings))
    p.update_landmarks(means)
    return p


def assert_path_valid(res, seg=segment_hits_box, T=T2):
    assert res.status == "ok", res.message
    P = res.configurations
    for a, b in zip(P[:-1], P[1:]):
        assert not seg(a, b)
    steps = np.diff(res.time_steps)
    assert np.all((steps >= 0) & (steps <= 2)) and res.time_steps[-1] == T - 1
    moved = np.any(P[1:] != P[:-1], axis=1)
    assert np.all(steps[moved] == 0) and np.all(steps[~moved] > 0)  # one kind of edge at a time


# ---------------------------------------------------------------- tests
@pytest.mark.parametrize("t0", [0, 3])
def test_search_matches_dijkstra_on_the_full_product_graph(toy, t0):
    means = arc_means(T2)
    q0 = np.array([-0.7, 0.05])
    res = make_planner(toy, means).plan(q0, t0)
    assert_path_valid(res)
    assert res.cost == pytest.approx(reference_cost(toy, means, trans_table(T2), q0, t0), rel=1e-9, abs=1e-9)
    assert res.stats["searches"] >= 1 and res.stats["segment_checks"] < toy.graph.number_of_edges()


@pytest.mark.parametrize("seed", range(8))
def test_random_problems_match_reference(seed):
    """Random roadmaps, horizons, forbidden transitions (stays too), start steps and goals."""
    rng = np.random.default_rng(100 + seed)
    rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, 2)), int(rng.integers(30, 90)), in_box,
                       segment_hits_box)
    T = int(rng.integers(3, 8))
    tc = -np.log(rng.dirichlet([1.0, 1.0, 1.0], size=T))
    tc[rng.random((T, 3)) < 0.15] = np.inf
    means = arc_means(T, rng.uniform(-0.3, 0.3))

    def free_point():
        q = rng.uniform(-1, 1, 2)
        return q if not in_box(q) else free_point()
    q0, t0 = free_point(), int(rng.integers(0, T))
    qg = free_point() if seed % 2 == 0 else None
    ref = reference_cost(rm, means, tc, q0, t0, q_goal=qg, quad_dt=0.05)
    p = make_planner(rm, means, trans=tc, quad_dt=0.05)
    res = p.plan(q0, t0, qg)
    if math.isinf(ref):
        assert res.status == "no_path"
    else:
        assert res.ok and res.cost == pytest.approx(ref, rel=1e-9, abs=1e-9)
        assert_path_valid(res, T=T)


def test_edges_without_interior_nodes_plan_with_a_callable_cost_and_match_dijkstra():
    """Every edge shorter than one node spacing (coarse ``quad_dt``): no edge has an interior
    quadrature node, so the callable step cost is asked about no configuration. It raised from
    ``prepare`` on zero rows (torch's reshape), at the build and at every later plan."""
    rng = np.random.default_rng(7)
    rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, 2)), 60, in_box, segment_hits_box)
    means, q0 = arc_means(T2), np.array([-0.7, 0.05])
    p = make_planner(rm, means, quad_dt=10.0)  # 10 s of motion per node: m = 1 on every edge
    assert int(np.max(p.edges.m)) == 1
    res = p.plan(q0, 0)
    assert res.ok and res.cost == pytest.approx(
        reference_cost(rm, means, trans_table(T2), q0, 0, quad_dt=10.0), rel=1e-9, abs=1e-9)
    rm.add_vertices(np.array([[0.6, 0.1], [0.62, 0.12]]))  # a growth whose new edges are all short
    assert p.plan(q0, 0).ok


def test_goal_configuration(toy):
    means = arc_means(T2)
    q0, qg = np.array([-0.7, 0.05]), np.array([0.7, 0.05])
    res = make_planner(toy, means).plan(q0, 0, q_goal=qg)
    assert_path_valid(res)
    np.testing.assert_array_equal(res.configurations[-1], qg)
    assert res.vertices[-1] == -2 and res.vertices[0] == -1
    assert res.cost == pytest.approx(reference_cost(toy, means, trans_table(T2), q0, 0, q_goal=qg), rel=1e-9)


def test_replan_after_landmark_move_matches_a_fresh_planner(toy):
    planner = make_planner(toy, arc_means(T2))
    q0 = np.array([-0.7, 0.05])
    first = planner.plan(q0, 0)
    again = planner.plan(q0, 0)
    assert again.cost == first.cost and again.n_edges_evaluated == 0  # nothing stale: nothing costed
    for shift in (0.1, -0.2):
        moved = arc_means(T2, shift)
        planner.update_landmarks(moved)
        res = planner.plan(q0, 2)
        assert res.n_edges_evaluated == len(planner.edges.ends)  # every edge costed again, in one batch
        fresh = make_planner(toy, moved)
        # no stale cost: the updated planner's edge and vertex costs equal a fresh planner's
        for a, b in zip(planner.edges.costs(), fresh.edges.costs()):
            np.testing.assert_array_equal(a, b)
        assert res.cost == pytest.approx(fresh.plan(q0, 2).cost, rel=1e-12)
        assert res.cost == pytest.approx(reference_cost(toy, moved, trans_table(T2), q0, 2), rel=1e-9)
        assert_path_valid(res)


def test_batched_costs_equal_costs_computed_edge_by_edge(toy):
    """``EdgeStore.costs`` (one batch over all edges, steps and quadrature nodes) against the
    line integral of each edge computed on its own."""
    means = arc_means(T2)
    p = make_planner(toy, means)
    ell, W = p.edges.costs()
    f = gaussian_factory()(means)
    V, tc = toy.vertices, trans_table(T2)
    np.testing.assert_allclose(ell, f(torch.as_tensor(np.array(V))).numpy() - FLOOR, rtol=1e-12, atol=1e-12)
    for e in range(0, len(W), 37):
        u, w = p.edges.ends[e]
        a, b = V[u], V[w]
        tau = np.max(np.abs(b - a) / VMAX2)
        m = max(1, math.ceil(tau / DT - 1e-9))
        vals = f(torch.as_tensor(a + (b - a) * np.linspace(0, 1, m + 1)[:, None])).numpy() - FLOOR
        mean = (vals[0] / 2 + vals[1:-1].sum(0) + vals[-1] / 2) / m
        np.testing.assert_allclose(W[e], tau / DT * (tc[:, 0] + mean), rtol=1e-10)


@pytest.mark.parametrize("t_min, blocked_every", [(0, 0), (1, 7)])
def test_cost_to_go_is_the_exact_distance_to_the_end(toy, t_min, blocked_every):
    """``cost_to_go`` (one scipy Dijkstra per step) equals networkx's Dijkstra from every node
    to the end of the task on the same graph: with no edge blocked (the search's optimistic
    graph), and with every 7th edge blocked and the search starting at step 1 (the cost-to-go
    of the steps before it left at 0)."""
    means = arc_means(T2)
    p = make_planner(toy, means)
    ell, W = p.edges.costs()
    E = len(p.edges.ends)
    blocked = np.zeros(E, dtype=bool)
    if blocked_every:
        blocked[::blocked_every] = True
    g = SearchGraph(graph=toy.graph, ends=p.edges.ends, src=np.zeros(0, int), dst=np.zeros(0, int), W=W, ell=ell,
                    blocked=blocked)
    trans = transition_table(trans_table(T2), (0, 1, 2))
    H = cost_to_go(g, trans, t_min)
    ref = nx.DiGraph()
    for e, (u, w) in enumerate(p.edges.ends):
        if blocked[e]:
            continue
        for t in range(T2):
            ref.add_edge((u, t), (w, t), weight=W[e, t])
            ref.add_edge((w, t), (u, t), weight=W[e, t])
    for v in range(toy.n):
        for t in range(T2):
            for k in (1, 2):
                if t + k < T2:
                    ref.add_edge((v, t), (v, t + k), weight=trans[t, k] + ell[v, t + k])
        ref.add_edge((v, T2 - 1), "end", weight=0.0)
    to_go = nx.single_source_dijkstra_path_length(ref.reverse(copy=False), "end")
    nodes = [n for n in to_go if n != "end" and n[1] >= t_min]
    got = np.array([H[v, t] for (v, t) in nodes])
    want = np.array([to_go[n] for n in nodes])
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    assert E > 0 and len(nodes) == toy.n * (T2 - t_min) and np.all(H[:, -1] == 0.0)
    assert np.all(H[:, :t_min] == 0.0)
    if blocked_every:  # the blocked edges made some way longer
        free = cost_to_go(SearchGraph(graph=toy.graph, ends=p.edges.ends, src=np.zeros(0, int),
                                      dst=np.zeros(0, int), W=W, ell=ell), trans, t_min)
        assert np.all(H >= free - 1e-9) and np.any(H > free + 1e-6)


def test_an_object_that_moved_is_checked_again_and_the_plan_equals_a_fresh_one():
    """The obstacle moves across the arc after a first plan: ``object_moved`` resets the
    blocked edges near its old place and makes the free ones near its new place stale, and the next plan equals Dijkstra on the new
    world (and a fresh planner's); edges far from both places keep their checks."""
    box = {"lo": BOX_LO.copy(), "hi": BOX_HI.copy()}

    def in_box_now(q):
        return bool(np.all(q >= box["lo"]) and np.all(q <= box["hi"]))

    def seg_now(q1, q2):
        return box_world(box["lo"], box["hi"])[1](q1, q2)

    def keypoints(Q):  # the configuration as a point in the plane z = 0 (twice: one "link")
        P = np.c_[np.asarray(Q, dtype=float), np.zeros(len(Q))]
        return np.stack([P, P], axis=1)

    rng = np.random.default_rng(3)
    rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, 2)), 200, in_box_now, seg_now)
    means, q0 = arc_means(T2), np.array([-0.7, 0.05])
    p = ClosedLoopPlanner(rm, step_cost(T2), trans_table(T2), DT, VMAX2, keypoint_fn=keypoints,
                          settings=PlannerSettings(sweep_margin=0.0))
    p.update_landmarks(means)
    assert_path_valid(p.plan(q0, 0), seg_now)
    old_c = 0.5 * (box["lo"] + box["hi"])
    radius = 0.5 * float(np.linalg.norm(box["hi"] - box["lo"]))
    box["lo"], box["hi"] = np.array([-0.45, 0.3]), np.array([-0.15, 0.85])  # to the arc's other side
    new_c = 0.5 * (box["lo"] + box["hi"])
    known = p.edges.state != UNKNOWN
    reset = p.object_moved(np.r_[old_c, 0.0], np.r_[new_c, 0.0], radius)
    assert 0 < reset
    res = p.plan(q0, 0)
    assert_path_valid(res, seg_now)
    assert res.cost == pytest.approx(reference_cost(rm, means, trans_table(T2), q0, 0, seg=seg_now), rel=1e-9)
    fresh = ClosedLoopPlanner(rm, step_cost(T2), trans_table(T2), DT, VMAX2)
    fresh.update_landmarks(means)
    assert res.cost == pytest.approx(fresh.plan(q0, 0).cost, rel=1e-9)
    # asked about, every edge known before the move answers right for the new world: the stale
    # free ones near the new place are checked again, the others keep their verdicts
    checks = p.edges.counters["segment_checks"]
    eids = np.flatnonzero(known)
    free = p.edges.check(eids)
    V = rm.vertices
    truth = np.array([seg_now(V[u], V[w]) for u, w in p.edges.ends[eids]])
    np.testing.assert_array_equal(free, ~truth)
    assert 0 < p.edges.counters["segment_checks"] - checks < len(eids)


def test_edge_integral_converges_with_resolution():
    """A quadratic step cost along a segment has a closed-form mean; the trapezoid error ~ 1/m^2."""
    rm = Roadmap(2, lambda q: False, lambda a, b: False)
    rm.add_vertices(np.array([[0.0, 0.0], [1.0, 0.5]]), check=False)
    mu = torch.tensor([[0.3, 0.6], [1.0, 0.0]])
    cost = CallableStepCost(lambda lm: (lambda Q: ((Q[:, None, :] - mu[None]) ** 2).sum(-1)), 2)
    a, b = np.array([0.0, 0.0]), np.array([1.0, 0.5])
    s = np.linspace(0, 1, 200001)
    exact_mean = np.mean(np.sum((a + (b - a) * s[:, None] - mu[0].numpy()) ** 2, 1))
    errs = []
    for quad_dt in (0.5, 0.1, 0.02):
        p = ClosedLoopPlanner(rm, cost, np.array([[0.0, 1.0], [0.0, np.inf]]), 0.1, [1.0, 1.0],
                              offsets=(0, 1), settings=PlannerSettings(quad_dt=quad_dt))
        p.update_landmarks(np.zeros(1))
        _, W = p.edges.costs()
        tau = 1.0  # max |dq| / vmax
        errs.append(abs(W[0, 0] - tau / 0.1 * exact_mean))
    assert errs[0] > errs[1] > errs[2] and errs[2] < 1e-3 * tau / 0.1
    assert errs[1] / errs[2] == pytest.approx(25.0, rel=0.05)  # second order


def test_a_model_sampled_fast_gets_nodes_as_fine_as_the_motion_not_the_rate():
    """A model whose time base is 1 ms (learned from 1 kHz recordings) used to get a quadrature
    node every millisecond of motion: 40 times the nodes of the pour's 25 Hz, and a powder roadmap
    outgrew 22 GB. By default nodes are now no finer than ``MIN_QUAD_DT``; the edge cost, an
    integral in the model's time base, stays within 0.2% of what the fine nodes give (the quadratic cost of
    ``test_edge_integral_converges_with_resolution``: second-order error), and an explicit
    ``quad_dt`` is still honoured."""
    from lfd.planning.quadrature import MIN_QUAD_DT

    rm = Roadmap(2, lambda q: False, lambda a, b: False)
    rm.add_vertices(np.array([[0.0, 0.0], [1.0, 0.5]]), check=False)
    mu = torch.tensor([[0.3, 0.6], [1.0, 0.0]])
    cost = CallableStepCost(lambda lm: (lambda Q: ((Q[:, None, :] - mu[None]) ** 2).sum(-1)), 2)
    W, m = {}, {}
    for quad_dt in (None, 0.001):
        p = ClosedLoopPlanner(rm, cost, np.array([[0.0, 1.0], [0.0, np.inf]]), 0.001, [1.0, 1.0],
                              offsets=(0, 1), settings=PlannerSettings(quad_dt=quad_dt))
        p.update_landmarks(np.zeros(1))
        W[quad_dt], m[quad_dt] = p.edges.costs()[1][0, 0], int(p.edges.m[0])
    assert m[None] == math.ceil(1.0 / MIN_QUAD_DT) and m[0.001] == 1000, m  # tau = 1 s of motion
    assert W[None] == pytest.approx(W[0.001], rel=2e-3), W  # 0.13% here


def test_d7_random_matches_reference():
    rng = np.random.default_rng(1)
    d, T = 7, 6
    rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, d)), 120, lambda q: False, lambda a, b: False)
    means = rng.uniform(-0.6, 0.6, (2, d))
    mu = means[0] + (means[1] - means[0]) * np.linspace(0, 1, T)[:, None]
    vmax = np.array([1.5] * 4 + [4.0] * 3)
    planner = ClosedLoopPlanner(rm, step_cost(T, 0.3, d), trans_table(T), DT, vmax)
    planner.update_landmarks(mu)
    q0 = rng.uniform(-1, 1, d)
    res = planner.plan(q0, 0)
    assert res.ok and res.configurations.shape == (len(res.time_steps), d)
    ref = reference_cost(rm, mu, trans_table(T), q0, 0, sigma=0.3, d=d, vmax=vmax, seg=lambda a, b: False)
    assert res.cost == pytest.approx(ref, rel=1e-9)


def test_statuses(toy):
    means = arc_means(T2)
    q0 = np.array([-0.7, 0.05])
    p = ClosedLoopPlanner(toy, step_cost(T2), trans_table(T2), DT, VMAX2)
    assert p.plan(q0, 0).status == "missing_landmark"  # no landmarks yet
    p.update_landmarks(np.full_like(means, np.nan))
    assert p.plan(q0, 0).status == "missing_landmark"

    needs_bowl = CallableStepCost(lambda lm: gaussian_factory()(lm["bowl"]), T2, FLOOR)
    p2 = ClosedLoopPlanner(toy, needs_bowl, trans_table(T2), DT, VMAX2)
    p2.update_landmarks({"cup": means})
    assert p2.plan(q0, 0).status == "missing_landmark"
    p2.update_landmarks({"bowl": means})
    assert p2.plan(q0, 0).ok

    p.update_landmarks(means)
    done = p.plan(q0, T2 - 1)  # already at the last step: the plan is where the robot is
    assert done.ok and done.configurations.shape == (1, 2) and done.cost == 0.0
    assert p.plan(np.array([0.3, 0.5]), 0).status == "start_in_collision"
    r = p.plan(q0, 0, q_goal=np.array([0.3, 0.5]))
    assert r.status == "goal_in_collision" and r.configurations.shape == (0, 2)
    stuck = trans_table(T2)
    stuck[3, 1:] = stuck[2, 2] = np.inf  # no way past step 3
    p3 = ClosedLoopPlanner(toy, step_cost(T2), stuck, DT, VMAX2)
    p3.update_landmarks(means)
    assert p3.plan(q0, 0).status == "no_path" and p3.plan(q0, 4).ok
    tight = ClosedLoopPlanner(toy, step_cost(T2), trans_table(T2), DT, VMAX2,
                              settings=PlannerSettings(max_expansions=3))
    tight.update_landmarks(means)
    assert tight.plan(q0, 0).status == "budget_exceeded"
    nan = CallableStepCost(lambda lm: (lambda Q: torch.full((len(Q), T2), float("nan"))), T2)
    bad = ClosedLoopPlanner(toy, nan, trans_table(T2), DT, VMAX2)
    bad.update_landmarks(means)
    assert bad.plan(q0, 0).status == "invalid_cost"
    below = CallableStepCost(gaussian_factory(), T2, floor=0.0)  # not a lower bound: refused
    worse = ClosedLoopPlanner(toy, below, trans_table(T2), DT, VMAX2)
    worse.update_landmarks(means)
    r = worse.plan(q0, 0)
    assert r.status == "invalid_cost" and "floor" in r.message
    with pytest.raises(ValueError, match="q_current"):
        p.plan(np.zeros(3), 0)
    with pytest.raises(ValueError, match="t_current"):
        p.plan(q0, T2)
    with pytest.raises(ValueError, match="trans_cost"):
        ClosedLoopPlanner(toy, step_cost(T2), -trans_table(T2), DT, VMAX2)


def test_time_step_reads_0d_arrays_and_tensors_and_refuses_bools_and_fractions():
    """t_current from a torch or numpy computation (a 0-d value) is read like an int; a bool,
    a fraction or a vector is refused as before."""
    for t in (2, 2.0, np.int64(2), np.array(2), torch.tensor(2), torch.tensor(2.0)):
        assert time_step(t, 5) == 2
    for t in (True, torch.tensor(True), np.bool_(True), 1.5, torch.tensor(1.5), torch.tensor([2]), 5, -1, None, "2"):
        with pytest.raises(ValueError, match="t_current"):
            time_step(t, 5)


def test_state_stays_bounded_over_many_replans(toy):
    planner = make_planner(toy, arc_means(T2))
    rng = np.random.default_rng(5)
    n_edges = toy.graph.number_of_edges()
    for i in range(40):
        if i % 3 == 0:
            planner.update_landmarks(arc_means(T2, rng.uniform(-0.2, 0.2)))
        q = rng.uniform(-1, 1, 2)
        if not in_box(q):
            planner.plan(q, int(rng.integers(0, T2)))
        assert len(planner.edges.ends) == n_edges and planner.edges.n_vertices == toy.n
    assert toy.n == 180 and toy.graph.number_of_edges() == n_edges  # start points never join the roadmap
    assert set(np.unique(planner.edges.state)) <= {UNKNOWN, FREE, BLOCKED}


def test_roadmap_growth_between_plans():
    rng = np.random.default_rng(6)
    rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, 2)), 120, in_box, segment_hits_box)
    means, q0 = arc_means(T2), np.array([-0.7, 0.05])
    planner = make_planner(rm, means)
    before = planner.plan(q0, 0)
    rm.add_vertices(rng.uniform(-1, 1, (60, 2)))
    after = planner.plan(q0, 0)
    assert before.ok and after.cost <= before.cost + 1e-9  # more vertices: never worse
    assert after.cost == pytest.approx(reference_cost(rm, means, trans_table(T2), q0, 0), rel=1e-9)


def test_path_checks_are_a_fraction_of_the_edges():
    """Lazy PRM: the plan checks the edges of the paths it returns, not the roadmap."""
    rng = np.random.default_rng(7)
    rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, 2)), 300, in_box, segment_hits_box)
    res = make_planner(rm, arc_means(T2)).plan(np.array([-0.7, 0.05]), 0)
    assert_path_valid(res)
    assert res.stats["segment_checks"] < 0.2 * rm.graph.number_of_edges()


def test_a_blocked_start_edge_is_counted_and_avoided():
    """The lazy checks of the temporary edges (from the start configuration into the roadmap)
    count in ``stats["blocked"]`` like the roadmap's: the first path's start edge is made to
    collide, nothing else does, and the plan equals Dijkstra's without that edge."""
    rng = np.random.default_rng(3)
    cut = []  # (q_start, neighbour) segments that collide

    def segment_fn(a, b):
        return any((np.array_equal(a, u) and np.array_equal(b, w)) or (np.array_equal(a, w) and np.array_equal(b, u))
                   for u, w in cut)

    rm = Roadmap.build(lambda n: rng.uniform(-1.0, 1.0, (n, 2)), 120, lambda q: False, segment_fn)
    q0 = np.array([-0.7, 0.05])
    free = make_planner(rm, arc_means(T2)).plan(q0, 0)
    assert free.status == "ok" and free.stats["blocked"] == 0
    first_hop = free.configurations[1]
    assert not np.array_equal(first_hop, q0)  # the first edge moves (a start edge, not a wait)
    cut.append((q0, first_hop))
    res = make_planner(rm, arc_means(T2)).plan(q0, 0)
    assert res.status == "ok" and res.stats["blocked"] == 1
    P = res.configurations
    assert not any(segment_fn(a, b) for a, b in zip(P[:-1], P[1:]))
    assert res.cost >= free.cost
    ref = reference_cost(rm, arc_means(T2), trans_table(T2), q0, 0, seg=segment_fn)
    assert res.cost == pytest.approx(ref, rel=1e-9)


def test_the_search_screen_checks_midpoints_and_the_construction_screen_every_node():
    """``EdgeStore.screen`` (the search's first look near a collision) checks one point per
    edge, its midpoint: an edge whose midpoint collides is blocked, one that collides elsewhere
    is left to the segment check. The screen of edges as they are added checks every
    quadrature node when the store is made; edges added later are left to the search's screens.
    Three vertices, two small boxes: one on edge 0-1's midpoint, one a quarter of the way along
    edge 0-2; edge 1-2 is free."""
    boxes: list = []

    def collides(q) -> bool:
        return any(bool(np.all(q >= lo) and np.all(q <= hi)) for lo, hi in boxes)

    def segment(q1, q2) -> bool:
        return any(collides(q1 + (q2 - q1) * s) for s in np.linspace(0.0, 1.0, 201))

    V = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    on_midpoint = (np.array([0.45, -0.05]), np.array([0.55, 0.05]))
    off_midpoint = (np.array([-0.05, 0.2]), np.array([0.05, 0.3]))

    def store():
        rm = Roadmap(2, collides, segment)
        rm.add_vertices(V, check=False)
        E = EdgeStore(rm, step_cost(T2), np.full(T2, 0.1), DT, np.ones(2))
        rows = {frozenset(map(int, E.ends[e])): e for e in range(len(E.ends))}
        assert set(rows) == {frozenset({0, 1}), frozenset({0, 2}), frozenset({1, 2})}
        assert (E.m >= 10).all()  # 1 m at 1 rad/s, nodes every 0.1 s
        return E, rows[frozenset({0, 1})], rows[frozenset({0, 2})], rows[frozenset({1, 2})]

    # the boxes appear after the edges were added: the search's screen finds one of them
    E, e01, e02, e12 = store()
    assert (E.state == UNKNOWN).all()
    boxes[:] = [on_midpoint, off_midpoint]
    E.invalidate(occupied=(np.zeros(3), 1.0))  # no keypoint_fn: every edge is near the ball
    before = E.counters["screened_points"]
    assert E.screen([e01, e02, e12]) == 1
    assert E.counters["screened_points"] - before == 3  # one point per edge
    assert E.state[e01] == BLOCKED and E.state[e02] == UNKNOWN and E.state[e12] == UNKNOWN
    assert E.check([e02, e12]).tolist() == [False, True]  # the segment check has the last word
    # the boxes are there when the edges are added: every node is checked, both edges blocked
    E, e01, e02, e12 = store()
    assert E.state[e01] == BLOCKED and E.state[e02] == BLOCKED and E.state[e12] == UNKNOWN
    # edges a regrowth adds later are not screened when added, only when the search reaches them
    rm = E.roadmap
    (v3,) = rm.add_vertices(np.array([[1.0, 1.0]]), check=False)
    rm.add_edges([(0, int(v3))])  # (already joined when k-nearest covers it); its midpoint (0.5, 0.5) is free
    before = E.counters["screened_points"]
    E.sync()
    (e03,) = [e for e in range(len(E.ends)) if set(E.ends[e]) == {0, int(v3)}]
    assert E.counters["screened_points"] == before and E.state[e03] == UNKNOWN
    boxes.append((np.array([0.7, 0.7]), np.array([0.8, 0.8])))  # on the new edge, off its midpoint
    assert E.screen([e03]) == 0 and E.check([e03]).tolist() == [False]


def test_an_object_that_leaves_frees_only_the_edges_it_blocked():
    """Two boxes; the one on the left leaves. Edges blocked by the wall on the right stay blocked
    even where their motion passes near the box that left (their witness, the configuration
    found colliding, lies in the wall); the edges the box blocked are reset, and their witness,
    tried first, settles those that still collide without a segment check. Every edge then
    answers right for the new world."""
    boxes = {"box": (np.array([0.1, 0.1]), np.array([0.3, 0.3])),
             "wall": (np.array([0.32, -0.6]), np.array([0.45, 0.6]))}

    def collides(q):
        return any(bool(np.all(q >= lo) and np.all(q <= hi)) for lo, hi in boxes.values())

    def segment(q1, q2):
        return any(collides(q1 + (q2 - q1) * s) for s in np.linspace(0.0, 1.0, 201))

    def keypoints(Q):  # the configuration as a point in the plane z = 0 (twice: one "link")
        P = np.c_[np.asarray(Q, dtype=float), np.zeros(len(Q))]
        return np.stack([P, P], axis=1)

    rng = np.random.default_rng(11)
    rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, 2)), 200, collides, segment)
    E = EdgeStore(rm, step_cost(T2), np.full(T2, 0.1), DT, VMAX2, keypoint_fn=keypoints, sweep_margin=0.0)
    V = rm.vertices
    centre, radius = np.array([0.2, 0.2, 0.0]), 0.15
    # how close each edge's motion comes to the box that leaves (the ball of radius ``radius``)
    s = np.linspace(0.0, 1.0, 201)
    Qs = V[E.ends[:, 0], None] + (V[E.ends[:, 1]] - V[E.ends[:, 0]])[:, None] * s[None, :, None]
    near = np.linalg.norm(Qs - centre[:2], axis=-1).min(1) <= radius
    before = E.state.copy()
    assert (before == BLOCKED).sum() > 20
    boxes.pop("box")
    truth = np.array([segment(V[u], V[w]) for u, w in E.ends])
    E.invalidate(vacated=(centre, radius))
    kept = (E.state == BLOCKED)
    assert truth[kept].all()  # nothing free is held blocked
    reset = (before == BLOCKED) & (E.state == UNKNOWN)
    assert reset.sum() > 0 and not truth[reset].all()
    # blocked by the wall, passing near the box: a test of the motion would have reset them too
    assert (kept & near).any() and reset.sum() < ((before == BLOCKED) & near).sum()
    witness0, segments0 = E.counters["witness_checks"], E.counters["segment_checks"]
    np.testing.assert_array_equal(E.check(np.flatnonzero(reset)), ~truth[reset])
    assert E.counters["witness_checks"] - witness0 == reset.sum()  # each had the construction screen's
    # some still collide at their witness (in the wall, near the box's place): no segment check
    assert 0 < reset.sum() - (E.counters["segment_checks"] - segments0) <= (reset & truth).sum()
    np.testing.assert_array_equal(E.check(np.arange(len(E.ends))), ~truth)


def test_an_object_that_leaves_keeps_blocked_what_the_callables_say_another_object_hit():
    """Two boxes that overlap, the collision callable naming what it hits ("box" first, then
    "wall"). When the box leaves (``vacated`` with its name), no edge whose witness hit only the
    wall is reset, fewer edges are reset than when the callable answers a bare True (the same
    roadmap), nothing free is held blocked, and every edge answers right for the new world; the
    witnesses in the overlap, named after the box, are renamed after the wall by the checks, so
    that when the wall leaves too every edge is free again."""
    boxes = {"box": (np.array([0.1, 0.1]), np.array([0.3, 0.3])),
             "wall": (np.array([0.2, -0.6]), np.array([0.45, 0.6]))}

    def hit(q):
        return next((n for n, (lo, hi) in boxes.items() if np.all(q >= lo) and np.all(q <= hi)), "")

    def segment(q1, q2):
        return any(hit(q1 + (q2 - q1) * s) for s in np.linspace(0.0, 1.0, 201))

    def keypoints(Q):
        P = np.c_[np.asarray(Q, dtype=float), np.zeros(len(Q))]
        return np.stack([P, P], axis=1)

    stores = {}
    for named in (True, False):
        rng = np.random.default_rng(11)
        rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, 2)), 200, hit if named else (lambda q: bool(hit(q))),
                           segment)
        stores[named] = EdgeStore(rm, step_cost(T2), np.full(T2, 0.1), DT, VMAX2, keypoint_fn=keypoints,
                                  sweep_margin=0.0)
    E, E_bare = stores[True], stores[False]
    np.testing.assert_array_equal(E.ends, E_bare.ends)
    np.testing.assert_array_equal(E.state, E_bare.state)
    V = E.roadmap.vertices
    s = np.linspace(0.0, 1.0, 201)
    Qs = V[E.ends[:, 0], None] + (V[E.ends[:, 1]] - V[E.ends[:, 0]])[:, None] * s[None, :, None]  # (E, 201, 2)
    in_box = np.array([[hit(x) == "box" for x in row] for row in Qs]).any(1)
    before = E.state.copy()
    centre, radius = np.array([0.2, 0.2, 0.0]), 0.15
    boxes.pop("box")
    truth = np.array([segment(V[u], V[w]) for u, w in E.ends])
    E.invalidate(vacated=(centre, radius, "box"))
    E_bare.invalidate(vacated=(centre, radius))
    reset = (before == BLOCKED) & (E.state == UNKNOWN)
    reset_bare = (before == BLOCKED) & (E_bare.state == UNKNOWN)
    assert truth[E.state == BLOCKED].all()  # nothing free is held blocked
    assert reset.any() and not (reset & ~in_box).any()  # only edges through the box's place
    assert (reset <= reset_bare).all() and reset.sum() < reset_bare.sum()
    assert ((before == BLOCKED) & ~truth).any() and reset[(before == BLOCKED) & ~truth].all()  # all it freed
    np.testing.assert_array_equal(E.check(np.arange(len(E.ends))), ~truth)
    boxes.pop("wall")
    E.invalidate(vacated=(np.array([0.325, 0.0, 0.0]), 0.62, "wall"))
    assert E.check(np.arange(len(E.ends))).all()


def test_a_few_infinite_edge_costs_leave_the_rest_of_the_step_to_the_search(toy):
    """A cost that is infinite in one region (a forbidden place) makes only the edges that touch it
    infinite: the cost-to-go must still let the search move elsewhere at those steps, and the plan
    equals Dijkstra on the full product graph (an estimate that took the whole step as immobile
    because of one infinite edge overestimated, and A* reported no path or a worse one)."""
    means = arc_means(T2)
    forbidden = lambda Q: Q[:, 1] < -0.3  # noqa: E731  (the arc lies above it: y >= 0)

    def factory(landmarks):
        base = gaussian_factory()(landmarks)

        def step_nll(Q):
            out = base(Q)
            return torch.where(forbidden(Q)[:, None], torch.inf, out)
        return step_nll

    cost = CallableStepCost(factory, T2, floor=2 * math.log(math.sqrt(2 * math.pi) * SIGMA))
    p = ClosedLoopPlanner(toy, cost, trans_table(T2), DT, VMAX2, settings=PlannerSettings())
    p.update_landmarks(means)
    _, W = p.edges.costs()
    assert np.isinf(W).any() and np.isfinite(W).any(axis=0).all()  # some edges at every step
    q0 = np.array([-0.7, 0.05])
    res = p.plan(q0, 0)
    G = reference_graph(toy, factory(means), trans_table(T2), DT, VMAX2, q0, cost.floor[0])
    want = nx.dijkstra_path_length(G, ("s", 0), "sink")
    assert_path_valid(res)
    assert res.cost == pytest.approx(want, rel=1e-9, abs=1e-9)
