"""RRT and BiRRT that advance one external sample at a time.

The sampler is not part of the planner: :meth:`~TreePlanner.step` takes the sample, so an
environment step is exactly one planner iteration (as OMPL's ``RRT::solve`` loop body:
sample -> nearest -> steer -> check -> add -> goal test), and any sampler (uniform,
learned, an RL policy) can drive the same planner. :meth:`~TreePlanner.run` takes a batch of
samples and consumes them in order as that many steps would, in one compiled call where the problem
offers compiled steering and checks (:mod:`gnn_mp_envs.core.loop`), else step after step; ``step``
stays the reference the compiled loop is tested against.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from gnn_mp_envs.core.loop import (BIRRT_LOOP, CHECKS, CONSUMED, EDGES, LAYOUT, MEET_A, MEET_B, RRT_LOOP, SOLVED,
                                   LoopArrays, TreeArrays, compiled_loop, next_tree)
from gnn_mp_envs.core.problem import Problem
from gnn_mp_envs.core.tree import TreeStore, solution_rows
from gnn_mp_envs.utils.compiled import announce_compilation


#: The problem methods the compiled loop stands for: a subclass that overrides one of them in Python (a
#: goal test switched off, a steer of its own) is planned by the Python planner, which calls them.
LOOP_METHODS = ("steer", "check_motion", "in_goal", "goal_connection", "distance", "nearest_row", "is_state_valid")


@functools.lru_cache(maxsize=None)
def loop_serves(cls: type) -> bool:
    """Whether the compiled loop may stand for ``cls``'s methods: none of :data:`LOOP_METHODS` is defined
    below the class that gives its ``compiled_kernel``."""
    mro = cls.__mro__
    below = mro[:mro.index(next(c for c in mro if "compiled_kernel" in vars(c)))]
    return not any(name in vars(c) for c in below for name in LOOP_METHODS)


@dataclass
class StepResult:
    """What one planner iteration did."""

    added: list[int] = field(default_factory=list)
    solved: bool = False
    #: Samples consumed (iterations): 1 for :meth:`TreePlanner.step`.
    consumed: int = 1


@dataclass
class Solution:
    """A start-to-goal path through the tree(s).

    ``nodes`` are the path's global node indices (start to goal), so the tree as it stood
    when path node k was inserted is the node rows ``0..nodes[k]-1`` (what the learned
    samplers' datasets are built from).
    """

    states: np.ndarray
    controls: np.ndarray
    length: float
    nodes: np.ndarray


class TreePlanner:
    """Shared bookkeeping of RRT and BiRRT: the node store, roots and the solution."""

    num_trees = 1
    #: BiRRT's trees balanced (:func:`~gnn_mp_envs.core.loop.next_tree`); RRT has one tree.
    balance = False

    def __init__(self, problem: Problem, max_nodes: int) -> None:
        self.problem = problem
        self.max_nodes = int(max_nodes)
        self.tree = TreeStore(self.max_nodes, problem.state_dim, problem.control_dim, self.num_trees,
                              getattr(problem, "nearest_metric", None))
        self.active_tree = 0
        self.solution: Solution | None = None
        self.iterations = 0
        self._table: np.ndarray | None = None      # the compiled loop's table of this planner's arrays
        self._kernel = self._loop = None
        self._bind(self._served_kernel())          # made ready to plan: the first sample goes straight in

    @property
    def solved(self) -> bool:
        return self.solution is not None

    def _nearest(self, x: np.ndarray, tree: int) -> int:
        return self.tree.nearest(x, tree, self.problem)

    def _extend(self, tree: int, target: np.ndarray, added: list[int], near: int | None = None) -> int | None:
        """One steer from the nearest node of ``tree`` (or ``near``) toward ``target``; new node index."""
        if self.tree.full:
            return None
        if near is None:
            near = self.tree.nearest(target, tree, self.problem)
        edge = self.problem.steer(self.tree.states[near], target)
        if edge is None:
            return None
        i = self.tree.add(edge.state, near, tree, edge.cost, edge.control)
        added.append(i)
        return i

    def _path(self, head: int, tail: int = -1) -> Solution:
        """The solution through node ``head`` (from its root) and, for BiRRT, from ``tail``'s parent to its
        root (:func:`~gnn_mp_envs.core.tree.path_nodes`); its length is the two nodes' costs-to-come."""
        t = self.tree
        nodes, states, controls, length = solution_rows(t.parent, t.states, t.controls, t.cost, head, tail)
        return Solution(states=states, controls=controls, length=length, nodes=nodes)

    def step(self, sample: np.ndarray) -> StepResult:  # pragma: no cover - abstract
        raise NotImplementedError

    #: The compiled loop's planner (:mod:`gnn_mp_envs.core.loop`).
    loop_kind = RRT_LOOP

    @property
    def compiled(self) -> bool:
        """Whether :meth:`run` consumes samples in the compiled loop: the problem offers a compiled kernel
        (``compiled_kernel()`` not None) and names its metric (the tree's exact k-d index)."""
        return self._served_kernel() is not None

    def run(self, samples: np.ndarray, budget: int | None = None) -> StepResult:
        """Consume ``samples`` (``(K, d)``) in order as ``K`` calls of :meth:`step` would, at most ``budget``
        of them, stopping after the one that solves the problem or fills the tree: the nodes added (in
        order), whether it solved, and how many samples were consumed."""
        if not (type(samples) is np.ndarray and samples.dtype == np.float64 and samples.ndim == 2
                and samples.flags.c_contiguous):
            samples = np.ascontiguousarray(samples, dtype=np.float64).reshape(-1, self.problem.state_dim)
        budget = len(samples) if budget is None else max(0, min(int(budget), len(samples)))
        kernel = self._served_kernel()
        if kernel is None or self.solution is not None:
            return self._run_steps(samples, budget)
        if kernel is not self._kernel:              # a kernel object serves its problem until its context changes
            self._bind(kernel)
        tree, problem, counters, result = self.tree, self.problem, self._counters, self._result
        first = int(tree._size[0])
        counters[0] = counters[1] = 0
        self.active_tree = self._loop(samples, self.loop_kind, self.active_tree, budget, problem.step_size,
                                      problem.goal_tolerance, self.balance, self._table, kernel.context)
        problem.edges_checked += int(counters[EDGES])
        problem.collision_checks += int(counters[CHECKS])
        consumed, solved = int(result[CONSUMED]), bool(result[SOLVED])
        self.iterations += consumed
        if solved:
            self._solve(int(result[MEET_A]), int(result[MEET_B]), 1 - self.active_tree)
        return StepResult(list(range(first, int(tree._size[0]))), solved, consumed)

    def _served_kernel(self):
        """The problem's compiled kernel where the compiled loop serves this planner, else None."""
        if self.tree.index is None or not loop_serves(type(self.problem)):
            return None
        return self.problem.compiled_kernel()

    def _bind(self, kernel) -> None:
        """The compiled loop of ``kernel`` (None: nothing to do) and the table of this planner's arrays, made
        when the planner is (so that planning starts with the first sample) and again for a new kernel."""
        if kernel is None or kernel is self._kernel:
            return
        self._kernel, self._loop = kernel, compiled_loop(kernel)
        announce_compilation(self._loop, f"the planning loop with its steer and checks, kind {kernel.tag!r}",
                             "a minute or two", "gnn_mp_envs/core/loop.py")
        if self._table is None:
            self._pack()

    def __getstate__(self) -> dict:
        """Pickled (and deep-copied) without the compiled loop's table: it holds the addresses of this
        planner's arrays, not of the copy's (rebuilt on the copy's first :meth:`run`)."""
        return {**self.__dict__, "_table": None, "_groups": None, "_kernel": None, "_loop": None}

    def _pack(self) -> None:
        """The table of this planner's arrays the compiled loop reads (they live as long as the planner)."""
        t, ix, d = self.tree, self.tree.index, self.problem.state_dim
        self._counters, self._result = np.zeros(2, dtype=np.int64), np.zeros(4, dtype=np.int64)
        self._groups = (TreeArrays(t.states, t.parent, t.cost, t.tree_id, t._size, t._tree_size),
                        ix.arrays,
                        LoopArrays(np.ascontiguousarray(self.problem.goal, dtype=np.float64), np.zeros(d), np.zeros(1),
                                   self._counters, self._result))
        self._table = LAYOUT.pack(self._groups)

    def _run_steps(self, samples: np.ndarray, budget: int) -> StepResult:
        """:meth:`run` as :meth:`step` after :meth:`step`."""
        out = StepResult(consumed=0)
        for sample in samples[:budget]:
            if out.consumed and self.tree.full:
                break
            result = self.step(sample)
            out.added.extend(result.added)
            out.consumed += 1
            if result.solved:
                out.solved = True
                break
        return out

    def _solve(self, i: int, j: int, tree: int) -> None:  # pragma: no cover - abstract
        raise NotImplementedError


class RRT(TreePlanner):
    """Rapidly-exploring random tree (LaValle 1998) from the start state."""

    num_trees = 1

    def __init__(self, problem: Problem, max_nodes: int) -> None:
        super().__init__(problem, max_nodes)
        self.tree.add(problem.start, -1, 0)

    def step(self, sample: np.ndarray) -> StepResult:
        self.iterations += 1
        result = StepResult()
        if self.solution is not None:
            return result
        i = self._extend(0, sample, result.added)
        if i is None:
            return result
        x = self.tree.states[i]
        if not self.problem.in_goal(x):
            link = self.problem.goal_connection(x) if not self.tree.full else None
            if link is None:
                return result
            i = self.tree.add(link.state, i, 0, link.cost, link.control)
            result.added.append(i)
        self._solve(i, -1, 0)
        result.solved = True
        return result

    def _solve(self, i: int, j: int, tree: int) -> None:
        """The solution ends at node ``i`` (in the goal)."""
        self.solution = self._path(i)


class BiRRT(TreePlanner):
    """RRT-Connect (Kuffner & LaValle 2000): extend one tree, connect the other, swap.

    Tree 0 grows from the start, tree 1 from the goal. The sample passed to
    :meth:`step` extends the *active* tree; the other tree then greedily connects
    toward the new node, and the roles swap, so consecutive samples alternate trees.
    With ``balance`` (VAMP's RRT-Connect default) the roles swap only while the other
    tree holds fewer than twice the nodes of the one just extended: a tree boxed in
    (a goal inside a shelf) is extended until it has grown, instead of every other
    sample going to the large tree (:func:`~gnn_mp_envs.core.loop.next_tree`). The
    observation's ``active_tree`` is the tree the next sample extends either way.
    """

    num_trees = 2
    loop_kind = BIRRT_LOOP

    def __init__(self, problem: Problem, max_nodes: int, balance: bool = False) -> None:
        if not problem.geometric:
            raise ValueError(f"BiRRT needs straight-line (geometric) edges; the {problem.task} "
                             "problem is kinodynamic: use planner='rrt'")
        self.balance = checked_balance("birrt", balance)
        super().__init__(problem, max_nodes)
        self.tree.add(problem.start, -1, 0)
        self.tree.add(problem.goal, -1, 1)

    def _connect(self, tree: int, target: np.ndarray, added: list[int]) -> int | None:
        """Extend ``tree`` toward ``target`` until it is reached (index) or blocked (None).

        A node of ``tree`` already at ``target`` (e.g. both trees sampled the same root)
        counts as reached: steering toward it would be a zero-length, refused motion.
        """
        near = self._nearest(target, tree)
        states, nearest_row = self.tree.states, self.problem.nearest_row
        while True:
            # the distance to ``near`` as the nearest scan measures it (compiled where the problem names its metric)
            if nearest_row(states[near:near + 1], target)[1] < 1e-9:
                return near
            near = self._extend(tree, target, added, near)
            if near is None:
                return None

    def step(self, sample: np.ndarray) -> StepResult:
        self.iterations += 1
        result = StepResult()
        if self.solution is not None:
            return result
        a = self.active_tree
        b = 1 - a
        i = self._extend(a, sample, result.added)
        if i is not None:
            j = self._connect(b, self.tree.states[i], result.added)    # a node's row never changes
            if j is not None:
                self._solve(i, j, a)
                result.solved = True
        # solved: the other tree, as the compiled loop leaves it (the episode is over)
        self.active_tree = b if result.solved else next_tree.py_func(a, b, self.tree._tree_size, self.balance)
        return result

    def _solve(self, i: int, j: int, tree: int) -> None:
        """The trees meet: node ``i`` of ``tree`` (just extended) and node ``j`` of the other."""
        from_start, from_goal = (i, j) if tree == 0 else (j, i)
        # The goal tree is walked from the meeting node toward its root; the meeting node itself
        # duplicates the start side's last state and is left out.
        self.solution = self._path(from_start, from_goal)


PLANNERS: dict[str, type[TreePlanner]] = {"rrt": RRT, "birrt": BiRRT}


def checked_balance(planner: str, balance: bool) -> bool:
    """``balance`` for planner ``planner`` (a name of :data:`PLANNERS`): a bool, and True only for BiRRT's two
    trees; else a one-line ValueError (the environment asks before it builds its task)."""
    if not isinstance(balance, (bool, np.bool_)):
        raise ValueError(f"balance must be True or False, got {balance!r}")
    if balance and planner != "birrt":
        raise ValueError(f"balance applies to BiRRT's two trees; planner {planner!r} grows one (use planner='birrt')")
    return bool(balance)


def make_planner(name: str, problem: Problem, max_nodes: int, balance: bool = False) -> TreePlanner:
    """Build a planner by name (``rrt`` or ``birrt``); ``balance``: BiRRT's balanced trees (:class:`BiRRT`)."""
    try:
        cls = PLANNERS[name]
    except KeyError:
        raise ValueError(f"unknown planner {name!r}; known: {sorted(PLANNERS)}") from None
    if checked_balance(name, balance):
        return cls(problem, max_nodes, True)
    return cls(problem, max_nodes)
