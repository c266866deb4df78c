"""RRT and BiRRT that advance one external sample at a time.

The sampler is not part of the planner: :meth:`step` takes the sample, so an
environment step is exactly one planner iteration (as OMPL's ``RRT::solve`` loop body:
sample -> nearest -> steer -> check -> add -> goal test), and any sampler (uniform,
learned, an RL policy) can drive the same planner.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gnn_mp_envs.core.problem import Problem
from gnn_mp_envs.core.tree import TreeStore


@dataclass
class StepResult:
    """What one planner iteration did."""

    added: list[int] = field(default_factory=list)
    solved: bool = False


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

    def __init__(self, problem: Problem, max_nodes: int) -> None:
        self.problem = problem
        self.max_nodes = int(max_nodes)
        self.tree = TreeStore(self.max_nodes, problem.state_dim, problem.control_dim, self.num_trees)
        self.active_tree = 0
        self.solution: Solution | None = None
        self.iterations = 0

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

    def _path(self, nodes: list[int]) -> Solution:
        """The root-to-node path ``nodes``; its length is the last node's cost-to-come."""
        t = self.tree
        return Solution(states=t.states[nodes].copy(), controls=t.controls[nodes].copy(),
                        length=float(t.cost[nodes[-1]]), nodes=np.asarray(nodes, dtype=np.int64))

    def step(self, sample: np.ndarray) -> StepResult:  # pragma: no cover - abstract
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
        self.solution = self._path(self.tree.path_to_root(i))
        result.solved = True
        return result


class BiRRT(TreePlanner):
    """RRT-Connect (Kuffner & LaValle 2000): extend one tree, connect the other, swap.

    Tree 0 grows from the start, tree 1 from the goal. The sample passed to
    :meth:`step` extends the *active* tree; the other tree then greedily connects
    toward the new node, and the roles swap, so consecutive samples alternate trees.
    """

    num_trees = 2

    def __init__(self, problem: Problem, max_nodes: int) -> None:
        if not problem.geometric:
            raise ValueError(f"BiRRT needs straight-line (geometric) edges; the {problem.task} "
                             "problem is kinodynamic: use planner='rrt'")
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
                from_start, from_goal = (i, j) if a == 0 else (j, i)
                head = self._path(self.tree.path_to_root(from_start))
                # The goal tree is walked from the meeting node toward its root; the meeting
                # node itself duplicates the last state of ``head`` and is dropped.
                tail = self.tree.path_to_root(from_goal)[::-1][1:]
                self.solution = Solution(
                    np.vstack([head.states, self.tree.states[tail]]),
                    np.vstack([head.controls, self.tree.controls[tail]]),
                    head.length + float(self.tree.cost[from_goal]),
                    np.concatenate([head.nodes, np.asarray(tail, dtype=np.int64)]))
                result.solved = True
        self.active_tree = b
        return result


PLANNERS: dict[str, type[TreePlanner]] = {"rrt": RRT, "birrt": BiRRT}


def make_planner(name: str, problem: Problem, max_nodes: int) -> TreePlanner:
    """Build a planner by name (``rrt`` or ``birrt``)."""
    try:
        cls = PLANNERS[name]
    except KeyError:
        raise ValueError(f"unknown planner {name!r}; known: {sorted(PLANNERS)}") from None
    return cls(problem, max_nodes)
