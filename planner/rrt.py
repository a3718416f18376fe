"""Kinodynamic RRT (OMPL ``ompl.control.RRT``) over the pouring state with a model precondition.

How one run works
-----------------
OMPL's C++ ``control::RRT`` owns the loop: it samples a target state (uniformly, or from the goal
region with probability ``goal_bias``), finds the nearest tree node with its C++ nearest-neighbour
structure and asks the state propagator to extend that node. Everything learned lives in Python:

* **Batched proposals (the propagator is the control sampler).** The OMPL 2.x nanobind bindings
  expose neither a ``ControlSampler`` nor a ``DirectedControlSampler`` constructor, so a Python
  control sampler cannot be installed. Instead, the propagator keeps a queue of *admissible*
  proposals per tree node. When a node is extended and its queue is empty, it draws a batch of
  K actions from :class:`~planner.sampling.ActionSampler`, runs the dynamics model **once** on
  the K-batch, drops transitions that cannot be useful (non-finite or out-of-bounds predictions,
  dead states, see below), runs the MDE **once** on the survivors and keeps those with
  ``mu + beta * sigma < d_max``. Each propagator call pops one queued transition. K starts at
  ``batch_min`` and doubles per refill of the same node up to ``batch_max``, so nodes that are
  extended once cost little and frontier nodes that are extended often get large batches.
  Proposals that reach the goal go to the front of their queue. The control that OMPL sampled
  (uniform in a dummy box) is ignored; the executed action is the popped proposal, recorded in
  the Python node table.
* **Rejected transitions never enter the tree.** When no admissible proposal is available the
  propagator marks the result invalid and the validity checker rejects it, so OMPL drops it.
* **Node ids in the state.** The OMPL state is a compound space: (x, y), theta, v_ctrl, v_tgt and
  a zero-weight "node id" component. The id links an OMPL tree node to the Python node table
  (parent, depth, action, predicted state, mu, sigma) and does not affect nearest-neighbour
  distances (weight 0). Distances are ``w0*|dxy| + w1*|dtheta| + w2*|dv_ctrl| + w3*|dv_tgt|``
  (the design's d, with theta split off the pose norm: every tree state is upright, so a random
  target's theta then shifts all distances equally instead of reweighting x, y).
* **At most ``max_actions`` actions.** Depth is tracked per node; a node at the depth limit gets
  no proposals, and from a node one step below the limit only transitions that reach the goal
  are admissible (any other child could never be part of a plan); such a node gets at most
  ``last_step_proposals`` tries.
* **Dead states** (``prune_dead_states``): spilled water and water in the target cup never come
  back and no water is added, so predicted states with spill above the limit, v_tgt above
  g + tol or v_ctrl + v_tgt below g - tol are not added to the tree.
* **Determinism.** All action and goal samples come from a seeded ``numpy.random.Generator``;
  OMPL's own RNG (target states, goal-bias coin) is reseeded with ``ompl.util.RNG.setSeed`` right
  before the OMPL objects of a run are created. The primary budget counts model evaluations, so
  a seed gives the same plan whenever the run ends by success, exhaustion or propagation budget;
  only a run cut by the wall-clock ``time_budget`` can depend on machine speed.
* **No OMPL object escapes a run**; results are numpy arrays. Callbacks never raise through OMPL:
  an exception inside one stops the search and is re-raised after OMPL has returned.
"""

from __future__ import annotations

import contextlib
import math
import time
import traceback
from typing import Iterator

import numpy as np
import torch
from threadpoolctl import ThreadpoolController

from task.threads import torch_threads

from .config import PlannerConfig
from .interfaces import SKILL_MOVE, STATE_DIM, DeviationEstimator, DynamicsModel, goal_distance
from .problems import validate_goal, validate_precondition, validate_start
from .results import CandidateSet, PlannerStats, PlanResult, Trajectory
from .sampling import ActionSampler

try:  # guarded so that the pure-numpy parts of `planner` import without OMPL
    from ompl import base as ob
    from ompl import control as oc
    from ompl import util as ou
except ImportError as _e:  # pragma: no cover - ompl is a declared dependency
    ob = oc = ou = None
    _OMPL_IMPORT_ERROR: ImportError | None = _e
else:
    _OMPL_IMPORT_ERROR = None

_META = 4  # index of the node-id subspace in the compound OMPL state
_INVALID = -1.0
_GOAL_EPS = 1e-12


def _log_level(name: str):
    return {
        "none": ou.LOG_NONE,
        "error": ou.LOG_ERROR,
        "warn": ou.LOG_WARN,
        "info": ou.LOG_INFO,
        "debug": ou.LOG_DEBUG,
    }[name]


@contextlib.contextmanager
def _ompl_log(name: str) -> Iterator[None]:
    """Set OMPL's (process-global) log level for the duration of a run, then restore it."""
    prev = ou.getLogLevel()
    ou.setLogLevel(_log_level(name))
    try:
        yield
    finally:
        ou.setLogLevel(prev)


def _seed_ompl(seed: int) -> None:
    """Reseed OMPL's seed generator; RNG instances created afterwards are then deterministic.

    OMPL logs an error when the seed is changed after RNGs were created (it still reseeds, which
    is what we rely on), so the message is silenced.
    """
    prev = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)
    try:
        ou.RNG.setSeed(int(seed))
    finally:
        ou.setLogLevel(prev)


_BLAS: list[ThreadpoolController] = []  # found once, after numpy's BLAS is loaded


def _one_blas_thread() -> contextlib.AbstractContextManager:
    """numpy's BLAS on one thread for the length of a run, then restored.

    Why: the planner's matmuls are a few hundred rows at most, where a second BLAS thread buys nothing on
    an idle CPU and, on a busy one (two planner workers on two cores), stalls them by orders of magnitude:
    a [3, 64, 128] x [3, 128, 128] matmul took 127 ms with two threads and 0.7 ms with one while other
    processes kept both cores busy. Results do not depend on the thread count (BLAS splits rows, not sums;
    ``benchmarks/planner_profile.py`` checks that plans stay identical)."""
    if not _BLAS:
        _BLAS.append(ThreadpoolController())
    return _BLAS[0].limit(limits=1, user_api="blas")


def _torch_dtype(obj: object, default: torch.dtype) -> torch.dtype:
    """Dtype a model expects: ``obj.dtype`` if set, else its first parameter/buffer, else default."""
    dt = getattr(obj, "dtype", None)
    if isinstance(dt, torch.dtype):
        return dt
    for holder in (obj, getattr(obj, "model", None)):
        if isinstance(holder, torch.nn.Module):
            for t in holder.parameters():
                return t.dtype
            for t in holder.buffers():
                if t.is_floating_point():
                    return t.dtype
    return default


def _torch_device(obj: object) -> torch.device:
    for holder in (obj, getattr(obj, "model", None)):
        if isinstance(holder, torch.nn.Module):
            for t in holder.parameters():
                return t.device
    return torch.device("cpu")


class _Queue:
    """Admissible transitions proposed for one node, consumed front to back."""

    __slots__ = ("nxt", "act", "mu", "sd", "gd", "pos", "size", "k", "total")

    def __init__(
        self, nxt: np.ndarray, act: np.ndarray, mu: np.ndarray, sd: np.ndarray, gd: np.ndarray, k: int, total: int
    ) -> None:
        self.nxt, self.act, self.mu, self.sd = nxt, act, mu, sd
        self.gd = gd  # goal distances of nxt, computed with the batch (one numpy call per refill, not per node)
        self.pos = 0
        self.size = len(nxt)
        self.k = k  # size of the batch that filled this queue
        self.total = total  # proposals evaluated for this node so far


class _Search:
    """Python side of one RRT run: node table, proposal queues, budgets, OMPL callbacks.

    Holds no OMPL object, so OMPL objects (which hold these callbacks) form no reference cycle
    with it and are freed when the run's scope ends.
    """

    def __init__(
        self,
        evaluator: "_Evaluator",
        config: PlannerConfig,
        start: np.ndarray,
        g: float,
        tol: float,
        beta: float,
        d_max: float,
        rng: np.random.Generator,
        propagation_budget: int,
        deadline: float,
    ) -> None:
        self.ev = evaluator
        self.c = config
        self.g, self.tol, self.beta, self.d_max = g, tol, beta, d_max
        # the band a fallback plan may end in (>= the aimed band): dead-state pruning, the last step and the
        # order of the proposal queues use it
        self.accept_tol = tol if config.accept_tol is None else max(tol, float(config.accept_tol))
        self.rng = rng
        self.sampler = evaluator.sampler
        self.budget = int(propagation_budget)
        self.deadline = deadline
        cap = 1024
        self.S = np.zeros((cap, STATE_DIM))
        self.A = np.zeros((cap, 3))
        self.mu = np.zeros(cap)
        self.sd = np.zeros(cap)
        self.parent = np.full(cap, -1, dtype=np.int64)
        self.depth = np.zeros(cap, dtype=np.int64)
        self.gdist = np.zeros(cap)
        self.S[0] = start
        self.gdist[0] = float(self._goal_dist(start))
        self.n = 1
        self.idle_limit = 20000  # expansions without progress that end the search: max(20000, 50 * n)
        self.queues: dict[int, _Queue] = {}
        #: nodes that will never get another proposal (at the depth limit, or their last-step tries spent):
        #: OMPL keeps choosing them as nearest nodes (~90 % of its extensions on the experiment's batches,
        #: benchmarks/planner_profile.py), so the propagator turns them away before any other work
        self.closed: set[int] = set()
        self.rows = 0
        self.mde_rows = 0
        self.expansions = 0
        self.rejected = 0
        self.idle = 0  # expansions since the last model evaluation or new node
        self.error: BaseException | None = None
        self.timed_out = False
        self.water = float(start[3] + start[4])
        self.lo = np.asarray(config.state_low)
        self.hi = np.asarray(config.state_high)

    # -- OMPL callbacks ---------------------------------------------------------------------
    def propagate(self, state, control, duration, result) -> None:  # noqa: ARG002
        """OMPL state propagator: extend the node ``state`` by one queued admissible transition."""
        self.expansions += 1
        try:
            pid = int(state[_META][0])
            nid = -1 if pid < 0 or pid in self.closed else self._take(pid)
            if nid < 0:
                self.idle += 1
                result[_META][0] = _INVALID
                return
            x, y, th, vc, vt = self.S[nid].tolist()
            xy = result[0]
            xy[0] = x
            xy[1] = y
            result[1][0] = th
            result[2][0] = vc
            result[3][0] = vt
            result[_META][0] = float(nid)
        except BaseException as e:  # never let an exception unwind through OMPL's C++ loop
            self._fail(e)
            result[_META][0] = _INVALID

    def _fail(self, e: BaseException) -> None:
        """Remember a callback error without its traceback's frames.

        The frames (via ``f_back``) reach the OMPL objects of the run; keeping them would keep
        those alive for as long as the exception lives (and make nanobind report leaks at exit).
        The formatted traceback is kept as an exception note instead.
        """
        if self.error is None:
            tb_text = "".join(traceback.format_exception(type(e), e, e.__traceback__))
            traceback.clear_frames(e.__traceback__)
            e.__traceback__ = None
            e.__context__ = None
            e.add_note("raised inside an OMPL callback of the planner; original traceback:\n" + tb_text)
            self.error = e

    # The remaining callbacks are trivial, but a KeyboardInterrupt can surface in any Python
    # code that OMPL calls, so each one catches everything as well.
    def is_valid(self, state) -> bool:
        """OMPL validity checker: a state is valid iff the propagator admitted it (id >= 0)."""
        try:
            return state[_META][0] >= 0.0
        except BaseException as e:
            self._fail(e)
            return False

    def goal_distance(self, state) -> float:
        """Goal distance (0 iff goal reached) of a tree node, precomputed in the batch."""
        try:
            nid = int(state[_META][0])
            return float(self.gdist[nid]) if nid >= 0 else math.inf
        except BaseException as e:
            self._fail(e)
            return math.inf

    def sample_goal(self, state) -> None:
        """A goal-region state for goal biasing: random position, upright, v_tgt = g, no spill."""
        try:
            c = self.c
            x = self.rng.uniform(*c.move_x)
            y = self.rng.uniform(*c.move_y)
            xy = state[0]
            xy[0] = min(max(x, c.state_low[0]), c.state_high[0])
            xy[1] = min(max(y, c.state_low[1]), c.state_high[1])
            state[1][0] = c.state_low[2]
            state[2][0] = max(0.0, self.water - self.g)
            state[3][0] = self.g
            state[_META][0] = _INVALID
        except BaseException as e:
            self._fail(e)

    def should_stop(self) -> bool:
        """OMPL termination condition, checked once per RRT iteration."""
        try:
            if self.error is not None or self.rows >= self.budget:
                return True
            if self.idle > self.idle_limit:
                return True
            if time.perf_counter() >= self.deadline:
                self.timed_out = True
                return True
            return False
        except BaseException as e:
            self._fail(e)
            return True

    # -- proposals ------------------------------------------------------------------------------
    def _take(self, pid: int) -> int:
        q = self.queues.get(pid)
        if q is None or q.pos >= q.size:
            if self.depth[pid] >= self.c.max_actions:
                self.closed.add(pid)
                return -1
            if self.depth[pid] + 1 >= self.c.max_actions:
                # last step: only a goal hit is admissible, which is rare, so a node gets a
                # bounded number of finishing attempts in small batches
                done = 0 if q is None else q.total
                k = min(self.c.batch_min, self.c.last_step_proposals - done)
                if k <= 0:
                    self.closed.add(pid)
                    return -1
            else:  # batches double per refill of the same node
                k = self.c.batch_min if q is None else min(2 * q.k, self.c.batch_max)
            k = min(k, self.budget - self.rows)
            if k <= 0:
                return -1
            q = self._refill(pid, k, 0 if q is None else q.total)
            self.queues[pid] = q
            if q.size == 0:
                return -1
        i = q.pos
        q.pos += 1
        return self._add_node(pid, q, i)

    def _refill(self, pid: int, k: int, total: int) -> _Queue:
        """Evaluate k sampled actions from node ``pid`` in one batch; queue the admissible ones.

        The dynamics model runs on all k; cheap structural filters (finite, bounds, dead
        states, last-step goal requirement) come next, and the MDE only sees the survivors --
        its O(n^2) predictive variance is the most expensive part of a propagation.
        """
        s = self.S[pid]
        acts = self.sampler.sample(k, self.rng)
        states = np.tile(s, (k, 1))
        nxt, stuck = self.ev.predict_next_stuck(states, acts)
        self.rows += k
        self.idle = 0
        ok = np.all(np.isfinite(nxt), axis=1)
        if self.c.clip_to_bounds:
            nxt = np.clip(nxt, self.lo, self.hi)
        else:
            ok &= np.all((nxt >= self.lo) & (nxt <= self.hi), axis=1)
        gd = self._goal_dist(nxt)
        at_goal = gd <= 0.0
        at_accept = at_goal if self.accept_tol == self.tol else self._accepted(nxt)  # the fallback band's hits
        if self.c.prune_dead_states:
            ok &= ~self._dead(nxt) & ~self._stuck_move(nxt, acts)
            if stuck is not None:  # the simulator ends a trajectory at its first contact
                ok &= ~stuck
        if self.depth[pid] + 1 >= self.c.max_actions:
            # a child at the depth limit is useless unless it is a goal (or, with a fallback band, in it)
            ok &= at_accept
        idx = np.flatnonzero(ok)
        mu = np.zeros(idx.size)
        sd = np.zeros(idx.size)
        if idx.size and self.ev.mde is not None:
            mu, sd = self.ev.deviation(states[idx], acts[idx])
            self.mde_rows += idx.size
            pre = mu + self.beta * sd < self.d_max
            self.rejected += int(idx.size - np.count_nonzero(pre))
            idx, mu, sd = idx[pre], mu[pre], sd[pre]
        if idx.size:
            # goal hits first; then, with a fallback band, its hits, so that they enter the tree at the node's
            # next extension, as they would as goals of the wide band: the run finds whatever the wide band finds
            order = np.argsort((~at_goal[idx]).astype(np.int8) + ~at_accept[idx], kind="stable")
            idx, mu, sd = idx[order], mu[order], sd[order]
        return _Queue(nxt[idx], acts[idx], mu, sd, gd[idx], k, total + k)

    def _dead(self, states: np.ndarray) -> np.ndarray:
        """States from which the goal is unreachable because water only ever moves "downhill".

        Spilled water and water in the target cup never come back, and no water is added, so
        a state with spill > spill_limit, v_tgt > g + tol or v_ctrl + v_tgt < g - tol cannot
        precede a goal state; nor can a cup left tilted (stuck mid-pour, |theta| > stuck_tilt).
        Keeping such states out of the tree saves most of the search.
        """
        vc, vt, tol = states[:, 3], states[:, 4], self.accept_tol
        return (
            (1.0 - vc - vt > self.c.spill_limit)
            | (vt > self.g + tol)
            | (vc + vt < self.g - tol)
            | (np.abs(states[:, 2]) > self.c.stuck_tilt)
        )

    def _stuck_move(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Moves predicted to stop short of their target (stuck on the way): the trajectory would end there."""
        move = np.rint(actions[:, 0]) == SKILL_MOVE
        miss = np.hypot(states[:, 0] - actions[:, 1], states[:, 1] - actions[:, 2])  # x, y vs move(x, y)
        return move & (miss > self.c.stuck_move)

    def _goal_dist(self, states: np.ndarray) -> np.ndarray:
        """Goal distance, exactly 0 iff ``goal_reached`` and at least ``_GOAL_EPS`` otherwise.

        OMPL's goal test is ``distance < threshold``; with threshold ``_GOAL_EPS`` this keeps
        OMPL's notion of "solved" identical to :func:`planner.interfaces.goal_reached`.
        """
        d = goal_distance(states, self.g, self.tol, self.c.spill_limit)
        return np.where(d > 0.0, np.maximum(d, 2 * _GOAL_EPS), 0.0)

    def _accepted(self, states: np.ndarray) -> np.ndarray:
        """Whether states end a plan within the fallback band ``accept_tol`` (spill within the limit)."""
        return goal_distance(states, self.g, self.accept_tol, self.c.spill_limit) <= 0.0

    def fallback_node(self) -> int | None:
        """The tree node within ``accept_tol`` whose v_tgt is closest to the goal; None when there is no wider
        band or no node in it. Ties go to the node added first (deterministic)."""
        if self.accept_tol == self.tol:
            return None
        S = self.S[: self.n]
        ok = np.flatnonzero(self._accepted(S))
        if not ok.size:
            return None
        return int(ok[np.argmin(np.abs(S[ok, 4] - self.g))])

    def _add_node(self, pid: int, q: _Queue, i: int) -> int:
        nid = self.n
        if nid >= len(self.S):
            self._grow()
        self.S[nid] = q.nxt[i]
        self.A[nid] = q.act[i]
        self.mu[nid] = q.mu[i]
        self.sd[nid] = q.sd[i]
        self.parent[nid] = pid
        self.depth[nid] = self.depth[pid] + 1
        self.gdist[nid] = q.gd[i]
        self.n = nid + 1
        self.idle_limit = max(20000, 50 * self.n)
        self.idle = 0
        return nid

    def _grow(self) -> None:
        for k in ("S", "A", "mu", "sd", "parent", "depth", "gdist"):
            a = getattr(self, k)
            b = np.empty((2 * len(a),) + a.shape[1:], dtype=a.dtype)
            b[: len(a)] = a
            setattr(self, k, b)

    # -- results --------------------------------------------------------------------------------
    def trajectory_to(self, nid: int) -> Trajectory:
        chain = []
        while nid > 0:
            chain.append(nid)
            nid = int(self.parent[nid])
        chain.reverse()
        idx = np.asarray(chain, dtype=np.int64)
        states = np.vstack([self.S[0:1], self.S[idx]])
        return Trajectory(actions=self.A[idx], states=states, mu=self.mu[idx], sigma=self.sd[idx])


class _Evaluator:
    """Batched dynamics + MDE evaluation with numpy in/out (the only place torch is touched)."""

    def __init__(self, dynamics: DynamicsModel, mde: DeviationEstimator | None, sampler: ActionSampler) -> None:
        self.dynamics = dynamics
        self.mde = mde
        self.sampler = sampler
        self.dyn_dtype = _torch_dtype(dynamics, torch.get_default_dtype())
        self.dyn_device = _torch_device(dynamics)
        np_path = getattr(dynamics, "predict_np", None)
        self.predict_np = np_path if callable(np_path) and self.dyn_device.type == "cpu" else None
        #: a model that knows which transitions get stuck (dynamics.ContactAwareDynamics) says so itself
        contacts = getattr(dynamics, "predict_np_contacts", None)
        self.predict_contacts = contacts if callable(contacts) else None
        self.mde_dtype = _torch_dtype(mde, torch.get_default_dtype()) if mde is not None else None
        self.mde_device = _torch_device(mde) if mde is not None else None

    def predict_next(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Next states [k, 5] for k (state, action) pairs, one batched model call (:meth:`predict_next_stuck`)."""
        return self.predict_next_stuck(states, actions)[0]

    def predict_next_stuck(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Next states [k, 5] and, for a model that predicts contacts, which rows get stuck ([k] bool; None
        for a model that does not: the caller then judges from the predicted poses).

        A CPU model's numpy path (``predict_np``, float64 arithmetic) when it has one: the planner's
        batches are small (tens of rows), where torch's per-call overhead is most of the cost."""
        k = len(actions)
        stuck = None
        if self.predict_np is None:
            nxt = self._predict_torch(states, actions)
        elif self.predict_contacts is not None:
            nxt, stuck = self.predict_contacts(np.asarray(states, float), np.asarray(actions, float))
            stuck = np.asarray(stuck, bool)
        else:
            nxt = self.predict_np(np.asarray(states, float), np.asarray(actions, float))
        nxt = np.asarray(nxt, dtype=float)
        if nxt.shape != (k, STATE_DIM):
            raise ValueError(f"dynamics model returned shape {tuple(nxt.shape)}, expected ({k}, {STATE_DIM})")
        return nxt, stuck

    def _predict_torch(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            s = torch.tensor(states, dtype=self.dyn_dtype, device=self.dyn_device)  # copies: inputs
            a = torch.tensor(actions, dtype=self.dyn_dtype, device=self.dyn_device)  # may be read-only
            nxt = self.dynamics.predict(s, a)
            return np.asarray(torch.as_tensor(nxt).detach().to("cpu", torch.float64).numpy(), dtype=float)

    def deviation(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """MDE mean [k] and std [k] (zeros without an MDE), one batched call."""
        k = len(actions)
        if self.mde is None:
            return np.zeros(k), np.zeros(k)
        with torch.no_grad():
            X = torch.as_tensor(np.concatenate([states, actions], axis=1))
            mean, std = self.mde.predict(X.to(self.mde_device, self.mde_dtype))
            mu = torch.as_tensor(mean).detach().to("cpu", torch.float64).reshape(-1).numpy()
            sd = torch.as_tensor(std).detach().to("cpu", torch.float64).reshape(-1).numpy()
        if mu.shape != (k,) or sd.shape != (k,):
            raise ValueError(f"MDE returned mean {mu.shape} / std {sd.shape}, expected ({k},)")
        return mu, sd

    def evaluate(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Both of the above (used by the bench's raw-throughput measurement)."""
        return self.predict_next(states, actions), *self.deviation(states, actions)


class Planner:
    """OMPL kinodynamic RRT with a learned dynamics model and an MDE precondition.

    ``dynamics`` propagates states; ``mde`` (``None`` = no precondition, every transition allowed)
    supplies ``mu, sigma`` so that a transition is admitted only if ``mu + beta * sigma < d_max``.
    ``mde`` and ``dynamics`` are plain attributes and may be swapped between calls (e.g. after
    refitting the MDE).
    """

    def __init__(
        self, dynamics: DynamicsModel, mde: DeviationEstimator | None = None, config: PlannerConfig | None = None
    ) -> None:
        if _OMPL_IMPORT_ERROR is not None:  # pragma: no cover
            raise ImportError("planner.Planner needs the `ompl` package (>= 2.0)") from _OMPL_IMPORT_ERROR
        self.config = config or PlannerConfig()
        self.dynamics = dynamics
        self.mde = mde
        self.sampler = ActionSampler(self.config)

    # -- public API -------------------------------------------------------------------------------
    def plan(
        self,
        start,
        goal: float,
        *,
        beta: float | None = None,
        d_max: float | None = None,
        tol: float | None = None,
        seed: int | np.random.SeedSequence | None = None,
        time_budget: float | None = None,
        propagation_budget: int | None = None,
    ) -> PlanResult:
        """One RRT run from ``start`` to ``|v_tgt - goal| <= tol`` with spill within the limit.

        Returns a :class:`PlanResult`; not finding a plan within the budgets is a normal result
        (``found == False``), never an exception. Invalid input raises ``ValueError``.
        """
        c = self.config
        s0 = validate_start(start, c)
        g, t = validate_goal(goal, c.goal_tol if tol is None else tol)
        b, d = validate_precondition(c.beta if beta is None else beta, c.d_max if d_max is None else d_max)
        tb = c.time_budget if time_budget is None else float(time_budget)
        pb = c.propagation_budget if propagation_budget is None else int(propagation_budget)
        if not tb > 0:
            raise ValueError(f"time_budget={time_budget!r} must be > 0 seconds")
        if pb < 1:
            raise ValueError(f"propagation_budget={propagation_budget!r} must be >= 1")
        return self._run(s0, g, t, b, d, run_seed_sequence(c, seed), tb, pb)

    def plan_candidates(
        self,
        start,
        goal: float,
        *,
        n: int | None = None,
        beta: float | None = None,
        d_max: float | None = None,
        tol: float | None = None,
        seed: int | None = None,
        time_budget: float | None = None,
        propagation_budget: int | None = None,
    ) -> CandidateSet:
        """``n`` (default ``config.n_candidates``) independent seeded RRT runs for one problem.

        Each run gets its own child seed of ``seed``, its own tree and its own budgets; the set
        holds the distinct trajectories that reached the goal (at most ``n``) and every run's
        statistics. ``seed=None`` means ``config.seed``: pass a different seed per problem
        (e.g. the problem index) when planning many problems. Diversity comes from independent
        trees: two runs practically never share a continuous action sequence, and exact
        duplicates are dropped.
        """
        runs = [
            self.plan(
                start,
                goal,
                beta=beta,
                d_max=d_max,
                tol=tol,
                seed=child,
                time_budget=time_budget,
                propagation_budget=propagation_budget,
            )
            for child in candidate_seeds(self.config, n, seed)
        ]
        return collect_candidates(runs)

    # -- internals --------------------------------------------------------------------------------
    def _run(
        self,
        start: np.ndarray,
        g: float,
        tol: float,
        beta: float,
        d_max: float,
        ss: np.random.SeedSequence,
        time_budget: float,
        propagation_budget: int,
    ) -> PlanResult:
        c = self.config
        t0 = time.perf_counter()
        np_seed, ompl_seed = run_seeds(ss)
        seed_repr = np_seed
        rng = np.random.default_rng(np.random.SeedSequence(np_seed))
        ev = _Evaluator(self.dynamics, self.mde, self.sampler)
        search = _Search(ev, c, start, g, tol, beta, d_max, rng, propagation_budget, t0 + time_budget)

        if search.gdist[0] <= 0.0:  # the start already satisfies the goal: the empty plan
            traj = search.trajectory_to(0)
            return PlanResult(traj, PlannerStats.unexpanded("trivial", seed_repr, 0.0, time.perf_counter() - t0))

        if c.prune_dead_states and bool(search._dead(start[None])[0]):
            # too much spilled / poured already or too little water left: no plan can exist
            stats = PlannerStats.unexpanded("unreachable", seed_repr, float(search.gdist[0]), time.perf_counter() - t0)
            return PlanResult(None, stats)

        with _ompl_log(c.ompl_log_level), torch_threads(c.torch_threads), _one_blas_thread():
            goal_node = self._solve_with_ompl(search, start, ompl_seed % (2**31 - 1) + 1)
        elapsed = time.perf_counter() - t0
        if search.error is not None:
            raise search.error
        found = goal_node is not None
        if not found:
            goal_node = search.fallback_node()  # the search ended without a centred plan: the best in the wide band
        if found:
            termination = "solved"
        elif goal_node is not None:
            found, termination = True, "accepted"
        elif search.rows >= search.budget:
            termination = "propagation_budget"
        elif search.timed_out:
            termination = "time_budget"
        else:
            termination = "exhausted"
        best = float(np.min(search.gdist[: search.n]))
        stats = PlannerStats(
            found=found,
            time_s=elapsed,
            propagations=search.rows,
            mde_evaluations=search.mde_rows,
            expansions=search.expansions,
            rejected=search.rejected,
            tree_size=search.n,
            termination=termination,
            seed=seed_repr,
            best_goal_distance=best,
        )
        traj = search.trajectory_to(goal_node) if found else None
        return PlanResult(traj, stats)

    def _solve_with_ompl(self, search: _Search, start: np.ndarray, ompl_seed: int) -> int | None:
        """Build the OMPL problem, run ``control::RRT``; return the goal node id (None: no plan).

        All OMPL objects are locals of this function and die with it.
        """
        c = self.config
        _seed_ompl(ompl_seed)
        lo, hi = c.state_low, c.state_high

        def rv(dims: list[int]):
            sp = ob.RealVectorStateSpace(len(dims))
            bounds = ob.RealVectorBounds(len(dims))
            for j, d in enumerate(dims):
                bounds.setLow(j, lo[d])
                bounds.setHigh(j, hi[d] if hi[d] > lo[d] else lo[d] + 1e-9)
            sp.setBounds(bounds)
            return sp

        meta = ob.RealVectorStateSpace(1)
        meta.setBounds(_INVALID, float(2**31))
        w = c.distance_weights
        space = ob.CompoundStateSpace([rv([0, 1]), rv([2]), rv([3]), rv([4]), meta], [w[0], w[1], w[2], w[3], 0.0])
        cspace = oc.RealVectorControlSpace(space, 3)
        cb = ob.RealVectorBounds(3)
        cb.setLow(0.0)
        cb.setHigh(1.0)
        cspace.setBounds(cb)
        si = oc.SpaceInformation(space, cspace)
        si.setStatePropagator(search.propagate)
        si.setStateValidityChecker(search.is_valid)
        si.setPropagationStepSize(1.0)
        si.setMinMaxControlDuration(1, 1)
        si.setup()

        st = si.allocState()
        st[0][0] = float(start[0])
        st[0][1] = float(start[1])
        st[1][0] = float(start[2])
        st[2][0] = float(start[3])
        st[3][0] = float(start[4])
        st[_META][0] = 0.0
        pdef = ob.ProblemDefinition(si)
        pdef.addStartState(st)
        goal = _GoalRegion(si, search)
        pdef.setGoal(goal)
        rrt = oc.RRT(si)
        rrt.setGoalBias(c.goal_bias)
        rrt.setProblemDefinition(pdef)
        rrt.setup()
        rrt.solve(ob.PlannerTerminationCondition(search.should_stop))

        found_node = None
        if pdef.hasExactSolution() and search.error is None:
            path = pdef.getSolutionPath()
            states = path.getStates()
            nid = int(states[-1][_META][0])
            if len(states) != search.depth[nid] + 1 or search.gdist[nid] > 0.0:
                # an internal inconsistency; raised by the caller, outside this frame, so that
                # the traceback does not hold the OMPL objects
                search.error = RuntimeError("OMPL solution path disagrees with the planner's node table")
            else:
                found_node = nid
        rrt.clear()
        pdef.clearGoal()
        return found_node


def run_seed_sequence(config: PlannerConfig, seed: int | np.random.SeedSequence | None) -> np.random.SeedSequence:
    """The seed sequence of one :meth:`Planner.plan` run: ``seed`` itself, or ``config.seed`` when None."""
    if isinstance(seed, np.random.SeedSequence):
        return seed
    return np.random.SeedSequence(config.seed if seed is None else int(seed))


def run_seeds(ss: np.random.SeedSequence) -> tuple[int, int]:
    """The run's numpy and OMPL seeds; the first is the one :class:`PlannerStats` reports."""
    np_seed, ompl_seed = ss.generate_state(2, dtype=np.uint32)
    return int(np_seed), int(ompl_seed)


def candidate_seeds(
    config: PlannerConfig, n: int | None = None, seed: int | None = None
) -> list[np.random.SeedSequence]:
    """Seeds of the ``n`` runs of :meth:`Planner.plan_candidates` (``None``: the config's values).

    Separate so that the runs can be planned elsewhere (:mod:`planner.pool`) and assembled by
    :func:`collect_candidates` into the same :class:`CandidateSet`.
    """
    n = config.n_candidates if n is None else int(n)
    if n < 1:
        raise ValueError(f"n={n} candidates must be >= 1")
    return np.random.SeedSequence(config.seed if seed is None else seed).spawn(n)


def collect_candidates(runs: list[PlanResult]) -> CandidateSet:
    """The candidate set of runs in seed order: the distinct trajectories found, every run's stats."""
    cands: list[Trajectory] = []
    for r in runs:
        if r.trajectory is not None and not any(r.trajectory.same_as(o) for o in cands):
            cands.append(r.trajectory)
    return CandidateSet(candidates=cands, runs=list(runs))


if ob is not None:

    class _GoalRegion(ob.GoalSampleableRegion):
        """Goal region over predicted states; sampleable so that RRT's goal bias works."""

        def __init__(self, si, search: _Search) -> None:
            super().__init__(si)
            self._search = search
            self.setThreshold(_GOAL_EPS)

        def distanceGoal(self, state) -> float:  # noqa: N802 (OMPL API name)
            return self._search.goal_distance(state)

        def sampleGoal(self, state) -> None:  # noqa: N802
            self._search.sample_goal(state)

        def maxSampleCount(self) -> int:  # noqa: N802
            return 2**31 - 1
