"""Spatiotemporal planning: lazy A* on the implicit product graph against plain networkx Dijkstra on
a fully evaluated product graph built here independently; replanning; statuses; bounded caches."""

import math

import networkx as nx
import numpy as np
import pytest
import torch

from lfd.planner import ClosedLoopPlanner, PlannerSettings
from lfd.roadmap import Roadmap, k_prm_star
from lfd.stcost import CostSettings, SpatiotemporalCosts
from helpers import box_world

# ---------------------------------------------------------------- toy world (d = 2)
BOX_LO, BOX_HI = np.array([0.15, 0.35]), np.array([0.45, 0.9])  # cuts the arc of the means
DT, T2 = 0.1, 8
VMAX2 = np.array([1.0, 2.0])


in_box, segment_hits_box = box_world(BOX_LO, BOX_HI)


def arc_means(T, shift=0.0):
    th = np.linspace(np.pi, 0.0, T) + shift
    return np.stack([0.7 * np.cos(th), 0.7 * np.sin(th)], axis=1)  # (T, 2)


def gaussian_factory(sigma=0.15):
    """a_hat = the per-step means (T, d); step_nll = Gaussian nll (negative near the means)."""
    def factory(a_hat):
        mu = torch.as_tensor(np.asarray(a_hat, dtype=float))
        const = mu.shape[1] * math.log(math.sqrt(2 * math.pi) * sigma)

        def step_nll(Q):
            return 0.5 * ((Q[:, None, :] - mu[None]) ** 2).sum(-1) / sigma ** 2 + const
        return step_nll
    return factory


def log_trans_table(T, p=(0.3, 0.5, 0.2)):
    return np.log(np.tile(np.asarray(p), (T, 1)))


@pytest.fixture(scope="module")
def toy():
    rng = np.random.default_rng(0)
    rm = Roadmap.build(lambda n: rng.uniform(-1.0, 1.0, (n, 2)), 180, in_box, segment_hits_box)
    return rm


# ---------------------------------------------------------------- independent reference
def occupancy_intervals(log_trans):
    """(T,) mean sampling intervals per run in each step: P(visit t) / (1 - p(t|t)), with the
    visit probabilities by forward recursion over offsets (0, 1, 2) (not lfd.timing's passage times)."""
    T = log_trans.shape[0]
    p_stay = np.minimum(np.exp(log_trans[:, 0]), 0.999)
    visit = np.zeros(T)
    visit[0] = 1.0
    for t in range(T - 1):
        for k_ in (1, 2):
            if t + k_ < T:
                visit[t + k_] += visit[t] * np.exp(log_trans[t, k_]) / (1 - p_stay[t])
    return visit / (1 - p_stay)


def reference_graph(rm, step_nll, log_trans, dt, vmax, q_start, quad_dt=None, floor=None,
                    q_goal=None, seg=segment_hits_box, dwell="interval"):
    """The fully evaluated, eagerly collision-checked product graph, nodes ((v | "s" | "g"), t).

    dwell="expected": a time edge leaving step t also pays p/(1-p) more intervals there
    (p = p(t|t)), each at -log p(t|t) plus the step cost of where it leaves from, and a step it
    skips 1 + p/(1-p) intervals at that configuration; dwell="occupancy" the same with the step's
    mean intervals per run, P(visit t) / (1 - p), less one, instead of p/(1-p)."""
    T = log_trans.shape[0]
    p_stay = np.minimum(np.exp(log_trans[:, 0]), 0.999)
    D = p_stay / (1 - p_stay) if dwell == "expected" else np.zeros(T)
    if dwell == "occupancy":
        D = np.maximum(occupancy_intervals(log_trans) - 1.0, 0.0)
        D[-1] = 0.0
    quad_dt = quad_dt or dt
    V = np.array(rm.vertices)
    n = len(V)
    L = lambda Q: step_nll(torch.as_tensor(Q)).numpy()  # noqa: E731
    LV = L(V)
    if floor is not None and np.ndim(floor) == 1:  # a bound per step, used as it is
        s = np.asarray(floor, dtype=float)
    else:
        s = min(0.0, LV.min() if floor is None else floor)
    ell = lambda raw: np.maximum(raw - s, 0.0)  # noqa: E731
    pos = {v: V[v] for v in range(n)}
    pos["s"] = q_start
    k = k_prm_star(n + 1, V.shape[1])
    edges = [(u, w) for u, w in rm.graph.edges if not seg(V[u], V[w])]
    nearest = lambda q: np.argsort(np.linalg.norm(V - q, axis=1))[:k]  # noqa: E731
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
        vals = ell(L(a + (b - a) * np.linspace(0, 1, m + 1)[:, None]))  # (m + 1, T)
        mean = (vals[0] / 2 + vals[1:-1].sum(0) + vals[-1] / 2) / m
        for t in range(T):
            c = tau / dt * (-log_trans[t, 0] + mean[t])
            G.add_edge((u, t), (w, t), weight=c)
            if u != "s" and w != "g":
                G.add_edge((w, t), (u, t), weight=c)
    for v, q in pos.items():
        lq = ell(L(q[None])[0])
        for t in range(T):
            for k_ in (1, 2):
                if t + k_ < T:
                    stay = 0.0
                    if dwell != "interval":  # leaving t (D_t intervals), skipping j (1 + D_j)
                        stay = sum(((j > t) + D[j]) * lq[j] - (D[j] * log_trans[j, 0] if D[j] > 0 else 0.0)
                                   for j in range(t, t + k_))
                    G.add_edge((v, t), (v, t + k_), weight=-log_trans[t, k_] + lq[t + k_] + stay)
        G.add_edge((v, T - 1), "sink", weight=0.0)
    return G


def reference_cost(rm, step_nll, log_trans, dt, vmax, q_start, t_start, q_goal=None, **kw):
    """Plain nx.dijkstra on the fully evaluated product graph."""
    G = reference_graph(rm, step_nll, log_trans, dt, vmax, q_start, q_goal=q_goal, **kw)
    target = "sink" if q_goal is None else ("g", log_trans.shape[0] - 1)
    try:
        return nx.dijkstra_path_length(G, ("s", t_start), target)
    except nx.NetworkXNoPath:
        return math.inf


def make_planner(rm, means, heuristic=True, **cost_kw):
    p = ClosedLoopPlanner(rm, gaussian_factory(), log_trans_table(len(means)), DT, VMAX2,
                          settings=PlannerSettings(cost=CostSettings(heuristic=heuristic,
                                                                     **cost_kw)))
    p.update_landmarks(means)
    return p


def assert_path_valid(res, rm):
    assert res.status == "ok", res.message
    P = res.configurations
    for a, b in zip(P[:-1], P[1:]):
        assert not segment_hits_box(a, b)
    steps = np.diff(res.time_steps)
    assert np.all((steps >= 0) & (steps <= 2)) and res.time_steps[-1] == T2 - 1
    moved = np.any(P[1:] != P[:-1], axis=1)
    assert np.all(steps[moved] == 0) and np.all(steps[~moved] > 0)  # one kind of edge at a time


# ---------------------------------------------------------------- tests
@pytest.mark.parametrize("dwell", ["interval", "expected", "occupancy"])
@pytest.mark.parametrize("edge_checks", ["path", "expand"])
@pytest.mark.parametrize("heuristic", [True, False])
def test_lazy_search_matches_dijkstra_on_the_full_product_graph(toy, heuristic, edge_checks, dwell):
    means = arc_means(T2)
    q0, t0 = np.array([-0.7, 0.05]), 0
    planner = make_planner(toy, means, heuristic=heuristic, edge_checks=edge_checks, dwell=dwell)
    res = planner.plan(q0, t0)
    assert_path_valid(res, toy)
    ref = reference_cost(toy, gaussian_factory()(means), log_trans_table(T2), DT, VMAX2, q0, t0, dwell=dwell)
    assert res.cost == pytest.approx(ref, rel=1e-9, abs=1e-9)
    n_roadmap_edges = toy.graph.number_of_edges()
    assert 0 < res.n_edges_evaluated <= n_roadmap_edges + 20


def test_replan_after_landmark_move_matches_a_fresh_planner(toy):
    planner = make_planner(toy, arc_means(T2))
    q0 = np.array([-0.7, 0.05])
    first = planner.plan(q0, 0)
    again = planner.plan(q0, 0)
    # only the per-plan edges of the start configuration are new
    assert again.cost == first.cost and again.n_edges_evaluated <= toy.k(toy.n + 1)
    for shift in (0.1, -0.2):
        moved = arc_means(T2, shift)
        planner.update_landmarks(moved)
        res = planner.plan(q0, 2)
        fresh = make_planner(toy, moved).plan(q0, 2)
        ref = reference_cost(toy, gaussian_factory()(moved), log_trans_table(T2), DT, VMAX2, q0, 2)
        assert res.cost == pytest.approx(fresh.cost, rel=1e-12)
        assert res.cost == pytest.approx(ref, rel=1e-9)
        assert_path_valid(res, toy)


def test_goal_configuration_and_known_floor(toy):
    means = arc_means(T2)
    q0, qg = np.array([-0.7, 0.05]), np.array([0.7, 0.05])
    floor = 2 * math.log(math.sqrt(2 * math.pi) * 0.15)  # the Gaussian's minimum: a true bound
    planner = make_planner(toy, means, nll_floor=floor)
    res = planner.plan(q0, 0, q_goal=qg)
    assert_path_valid(res, toy)
    np.testing.assert_array_equal(res.configurations[-1], qg)
    assert res.vertices[-1] == -2 and res.vertices[0] == -1
    ref = reference_cost(toy, gaussian_factory()(means), log_trans_table(T2), DT, VMAX2, q0, 0,
                         floor=floor, q_goal=qg)
    assert res.cost == pytest.approx(ref, rel=1e-9)


@pytest.mark.parametrize("edge_checks", ["path", "expand"])
def test_per_step_floor_matches_dijkstra(toy, edge_checks):
    """A floor per time step (what TaskPlanner passes: s log|Sigma_t|) shifts each step's cost
    by its own bound; the lazy A* still returns Dijkstra's optimum of that graph, and the
    shifted costs are the raw ones minus each step's bound."""
    means = arc_means(T2)
    base = 2 * math.log(math.sqrt(2 * math.pi) * 0.15)  # the Gaussian's minimum, every step
    floor = tuple(base - 0.3 * t for t in range(T2))  # still a true bound, a different one per step
    planner = make_planner(toy, means, nll_floor=floor, edge_checks=edge_checks)
    q0 = np.array([-0.7, 0.05])
    res = planner.plan(q0, 0)
    assert_path_valid(res, toy)
    ref = reference_cost(toy, gaussian_factory()(means), log_trans_table(T2), DT, VMAX2, q0, 0, floor=floor)
    assert res.cost == pytest.approx(ref, rel=1e-9)
    raw = gaussian_factory()(means)(torch.as_tensor(toy._buf[:5])).numpy()
    np.testing.assert_allclose(planner.costs.ell(raw), raw - np.asarray(floor), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match=f"nll_floor to be one finite number or {T2}"):
        make_planner(toy, means, nll_floor=(0.0, 1.0))


@pytest.mark.parametrize("dwell", ["interval", "expected", "occupancy"])
@pytest.mark.parametrize("t_start", [0, 3])
def test_heuristic_is_admissible_and_consistent(toy, t_start, dwell):
    means = arc_means(T2)
    costs = SpatiotemporalCosts(toy, log_trans_table(T2), DT, VMAX2, settings=CostSettings(dwell=dwell))
    costs.set_step_nll(gaussian_factory()(means))
    q0 = np.array([-0.7, 0.05])
    costs.set_temporary({-1: q0}, {-1: toy.connect_point(q0)})
    costs.prepare(t_start)
    G = reference_graph(toy, gaussian_factory()(means), log_trans_table(T2), DT, VMAX2, q0, dwell=dwell)
    to_go = nx.single_source_dijkstra_path_length(G.reverse(copy=False), "sink")

    def h(node):
        if node == "sink":
            return 0.0
        return costs.heuristic(-1 if node[0] == "s" else node[0], node[1])
    for node, dist in to_go.items():  # exact cost-to-go from every node >= h
        assert h(node) <= dist + 1e-9
    for a, b, c in G.edges(data="weight"):  # consistency: h(a) <= c(a, b) + h(b)
        assert h(a) <= c + h(b) + 1e-9
    assert max(h((v, 0)) for v in range(toy.n)) > costs.heuristic(0, T2 - 1) == 0.0


def test_edge_integral_converges_with_resolution():
    """A quadratic step cost along a segment has a closed-form mean; the trapezoid error ~ 1/m^2."""
    rm = Roadmap(2, lambda q: False, lambda a, b: False)
    rm.add_vertices(np.array([[0.0, 0.0], [1.0, 0.5]]), check=False)
    mu = torch.tensor([[0.3, 0.6]])  # T = 1 ... plus a second step
    mu = torch.cat([mu, torch.tensor([[1.0, 0.0]])])
    f = lambda Q: ((Q[:, None, :] - mu[None]) ** 2).sum(-1)  # noqa: E731  (>= 0: no shift)
    a, b = np.array([0.0, 0.0]), np.array([1.0, 0.5])
    exact_mean = [np.mean(np.sum((a + (b - a) * s[:, None] - m) ** 2, 1))
                  for m, s in [(mu[0].numpy(), np.linspace(0, 1, 200001))] * 1]
    errs = []
    for quad_dt in (0.5, 0.1, 0.02):
        c = SpatiotemporalCosts(rm, np.log([[1.0, 1e-300, 1e-300]] * 2), 0.1, [1.0, 1.0],
                                settings=CostSettings(quad_dt=quad_dt, nll_floor=0.0))
        c.set_step_nll(f)
        c.set_temporary({}, {})
        c.prepare()
        nbrs, C = c.spatial(0)
        tau = 1.0  # max |dq| / vmax
        errs.append(abs(C[0, 0] - tau / 0.1 * exact_mean[0]))
    assert errs[0] > errs[1] > errs[2] and errs[2] < 1e-3 * tau / 0.1
    assert errs[1] / errs[2] == pytest.approx(25.0, rel=0.05)  # second order


def test_d7_random_matches_reference():
    rng = np.random.default_rng(1)
    d, T = 7, 6
    rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, d)), 120, lambda q: False,
                       lambda a, b: False)
    means = rng.uniform(-0.6, 0.6, (2, d))
    mu = means[0] + (means[1] - means[0]) * np.linspace(0, 1, T)[:, None]
    vmax = np.array([1.5] * 4 + [4.0] * 3)
    f = gaussian_factory(0.3)
    planner = ClosedLoopPlanner(rm, f, log_trans_table(T), DT, vmax)
    planner.update_landmarks(mu)
    q0 = rng.uniform(-1, 1, d)
    res = planner.plan(q0, 0)
    assert res.ok and res.configurations.shape == (len(res.time_steps), d)
    ref = reference_cost(rm, f(mu), log_trans_table(T), DT, vmax, q0, 0, seg=lambda a, b: False)
    assert res.cost == pytest.approx(ref, rel=1e-9)


def test_statuses(toy):
    means = arc_means(T2)
    q0 = np.array([-0.7, 0.05])
    p = ClosedLoopPlanner(toy, gaussian_factory(), log_trans_table(T2), DT, VMAX2)
    assert p.plan(q0, 0).status == "missing_landmark"  # no landmarks yet
    p.update_landmarks(np.full_like(means, np.nan))
    assert p.plan(q0, 0).status == "missing_landmark"

    def needs_bowl(a_hat):
        return gaussian_factory()(a_hat["bowl"])
    p2 = ClosedLoopPlanner(toy, needs_bowl, log_trans_table(T2), DT, VMAX2)
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
    stuck = log_trans_table(T2)
    stuck[3, 1:] = stuck[2, 2] = -np.inf  # no way past step 3
    p3 = ClosedLoopPlanner(toy, gaussian_factory(), stuck, DT, VMAX2)
    p3.update_landmarks(means)
    assert p3.plan(q0, 0).status == "no_path" and p3.plan(q0, 4).ok
    tight = ClosedLoopPlanner(toy, gaussian_factory(), log_trans_table(T2), DT, VMAX2,
                              settings=PlannerSettings(max_expansions=3))
    tight.update_landmarks(means)
    assert tight.plan(q0, 0).status == "budget_exceeded"
    bad = ClosedLoopPlanner(toy, lambda a: (lambda Q: torch.full((len(Q), T2), float("nan"))),
                            log_trans_table(T2), DT, VMAX2)
    bad.update_landmarks(means)
    assert bad.plan(q0, 0).status == "invalid_cost"

    def broken(a_hat):
        def step_nll(Q):
            raise RuntimeError("model exploded")
        return step_nll
    worse = ClosedLoopPlanner(toy, broken, log_trans_table(T2), DT, VMAX2)
    worse.update_landmarks(means)
    r = worse.plan(q0, 0)
    assert r.status == "invalid_cost" and "model exploded" in r.message
    with pytest.raises(ValueError, match="q_current"):
        p.plan(np.zeros(3), 0)
    with pytest.raises(ValueError, match="t_current"):
        p.plan(q0, T2)


def test_model_object_protocol(toy):
    class Model:
        def set_landmarks(self, a_hat):
            self.fn = gaussian_factory()(a_hat)

        def step_nll(self, Q):
            return self.fn(Q)

    p = ClosedLoopPlanner(toy, Model(), log_trans_table(T2), DT, VMAX2)
    p.update_landmarks(arc_means(T2))
    assert p.plan(np.array([-0.7, 0.05]), 0).ok


def test_caches_stay_bounded_over_many_replans(toy):
    planner = make_planner(toy, arc_means(T2))
    rng = np.random.default_rng(5)
    n_edges = toy.graph.number_of_edges()
    for i in range(60):
        if i % 3 == 0:
            planner.update_landmarks(arc_means(T2, rng.uniform(-0.2, 0.2)))
        q = rng.uniform(-1, 1, 2)
        planner.plan(q, int(rng.integers(0, T2)))
        c = planner.costs
        assert len(c._ecost) == toy.n_edge_ids and len(c._out) <= toy.n + 2
        assert len(c._temp) <= 2 and len(c._tedge) <= 2 * toy.k(toy.n + 1) + 1
    assert toy.n == 180
    assert toy.graph.number_of_edges() == n_edges  # start points never become roadmap edges


def test_roadmap_growth_between_plans(toy):
    rng = np.random.default_rng(6)
    rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, 2)), 120, in_box, segment_hits_box)
    means, q0 = arc_means(T2), np.array([-0.7, 0.05])
    planner = make_planner(rm, means)
    before = planner.plan(q0, 0)
    rm.add_vertices(rng.uniform(-1, 1, (60, 2)))
    after = planner.plan(q0, 0)
    ref = reference_cost(rm, gaussian_factory()(means), log_trans_table(T2), DT, VMAX2, q0, 0)
    assert before.ok and after.cost == pytest.approx(ref, rel=1e-9)  # the floor may move: no order


@pytest.mark.parametrize("dwell", ["interval", "expected", "occupancy"])
@pytest.mark.parametrize("seed", range(6))
def test_random_problems_match_reference(seed, dwell):
    """Random roadmaps, horizons, forbidden transitions (stays too), start steps and goals; both
    the plain time bound (0 sweeps) and the relaxed heuristic give the reference Dijkstra cost."""
    rng = np.random.default_rng(100 + seed)
    rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, 2)), int(rng.integers(30, 90)), in_box,
                       segment_hits_box)
    T = int(rng.integers(3, 8))
    lt = np.log(rng.dirichlet([1.0, 1.0, 1.0], size=T))
    lt[rng.random((T, 3)) < 0.15] = -np.inf
    means = arc_means(T, rng.uniform(-0.3, 0.3))

    def free_point():
        q = rng.uniform(-1, 1, 2)
        return q if not in_box(q) else free_point()
    q0, t0 = free_point(), int(rng.integers(0, T))
    qg = free_point() if seed % 2 == 0 else None
    ref = reference_cost(rm, gaussian_factory()(means), lt, DT, VMAX2, q0, t0, q_goal=qg,
                         quad_dt=0.05, dwell=dwell)
    for sweeps, checks in ((0, "path"), (3, "path"), (3, "expand")):
        p = ClosedLoopPlanner(rm, gaussian_factory(), lt, DT, VMAX2, settings=PlannerSettings(
            cost=CostSettings(heuristic_sweeps=sweeps, quad_dt=0.05, edge_checks=checks, dwell=dwell)))
        p.update_landmarks(means)
        res = p.plan(q0, t0, qg)
        if math.isinf(ref):
            assert res.status == "no_path"
        else:
            assert res.ok and res.cost == pytest.approx(ref, rel=1e-9, abs=1e-9)


def test_path_checking_finds_the_same_plan_with_fewer_segment_checks():
    """Lazy PRM (edges checked on the returned path, colliding ones dropped, search again) gives
    the cost of checking every expanded vertex's edges, for a fraction of the segment checks."""
    counts, costs = {}, {}
    for checks in ("expand", "path"):
        rng = np.random.default_rng(7)
        rm = Roadmap.build(lambda n: rng.uniform(-1, 1, (n, 2)), 300, in_box, segment_hits_box)
        p = make_planner(rm, arc_means(T2), edge_checks=checks)
        res = p.plan(np.array([-0.7, 0.05]), 0)
        assert_path_valid(res, rm)
        counts[checks], costs[checks] = res.stats["segment_checks"], res.cost
    assert costs["path"] == pytest.approx(costs["expand"], rel=1e-9)
    assert counts["path"] < 0.5 * counts["expand"]


@pytest.mark.parametrize("weighed", ["expected", "occupancy"])
def test_dwell_weighs_steps_by_their_stay(toy, weighed):
    """With a sticky step (p(t|t) = 0.9: 9 more intervals expected, and most runs enter it) the
    expected and the occupancy dwell move the plan to a better configuration for that step, where
    one interval per step holds on."""
    means = arc_means(T2)
    lt = log_trans_table(T2)
    lt[4] = np.log([0.9, 0.08, 0.02])
    q0 = np.array([-0.7, 0.05])
    err = {}
    for dwell in ("interval", weighed):
        p = ClosedLoopPlanner(toy, gaussian_factory(), lt, DT, VMAX2,
                              settings=PlannerSettings(cost=CostSettings(dwell=dwell)))
        p.update_landmarks(means)
        res = p.plan(q0, 0)
        assert_path_valid(res, toy)
        # where the robot stays through step 4: the last configuration at step 4 or before (a
        # skip 3 -> 5 holds it through step 4)
        q4 = res.configurations[np.flatnonzero(res.time_steps <= 4)[-1]]
        err[dwell] = float(np.linalg.norm(q4 - means[4]))
        assert res.cost == pytest.approx(reference_cost(toy, gaussian_factory()(means), lt, DT, VMAX2, q0, 0,
                                                        dwell=dwell), rel=1e-9)
    assert err[weighed] < 0.5 * err["interval"], err


def test_occupancy_dwell_weighs_a_rarely_entered_step_by_its_share(toy):
    """A sticky step that most runs skip (one demonstration stayed in it): the expected dwell
    charges its full stay, the occupancy dwell only the share of runs that enter it, which is
    the time the executor holds it (lfd.timing.step_clock)."""
    lt = log_trans_table(T2)
    lt[2] = np.log([0.3, 0.69, 0.01])   # step 3 always entered,
    lt[3] = np.log([0.3, 0.05, 0.65])   # step 4 entered from it 1 time in 14,
    lt[4] = np.log([0.95, 0.03, 0.02])  # and stayed in for 20 intervals
    D = {d: SpatiotemporalCosts(toy, lt, DT, VMAX2, settings=CostSettings(dwell=d)).dwell
         for d in ("expected", "occupancy")}
    occ = occupancy_intervals(lt)
    assert D["expected"][4] == pytest.approx(19.0)
    assert occ[4] < 2.0 and D["occupancy"][4] == pytest.approx(max(occ[4] - 1.0, 0.0), abs=1e-9)
    assert D["occupancy"][:-1] == pytest.approx(np.maximum(occ[:-1] - 1.0, 0.0), abs=1e-9)


def test_bad_dwell_option():
    with pytest.raises(ValueError, match="dwell in"):
        CostSettings(dwell="forever")
    with pytest.raises(ValueError, match="trans_scale > 0"):
        CostSettings(trans_scale=0.0)


@pytest.mark.parametrize("dwell", ["expected", "occupancy"])
def test_dwell_reads_p_through_the_scale(toy, dwell):
    """TaskPlanner hands the costs 2 log p (Eq. 3 units) with trans_scale=2: the dwell must come
    out of the real p (p/(1-p), or the occupancy less one), as with log p and scale 1."""
    lt = log_trans_table(T2, p=(0.8, 0.15, 0.05))
    one = SpatiotemporalCosts(toy, lt, DT, VMAX2, settings=CostSettings(dwell=dwell))
    two = SpatiotemporalCosts(toy, 2 * lt, DT, VMAX2, settings=CostSettings(dwell=dwell, trans_scale=2.0))
    expected = (np.full(T2, 0.8 / 0.2) if dwell == "expected"
                else np.maximum(occupancy_intervals(lt) - 1.0, 0.0))
    expected[-1] = 0.0
    np.testing.assert_allclose(one.dwell, expected, rtol=1e-12)
    np.testing.assert_allclose(two.dwell, expected, rtol=1e-12)
    np.testing.assert_allclose(two.stay_cost, 2 * one.stay_cost, rtol=1e-12)  # in the units of log_trans


def test_bad_edge_checks_option():
    with pytest.raises(ValueError, match="edge_checks"):
        CostSettings(edge_checks="eager")
