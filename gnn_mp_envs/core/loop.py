"""The compiled planning loop: RRT and BiRRT over a batch of samples in one compiled call, for problems
whose steering and edge checks are compiled (:class:`CompiledKernel`).

It is :class:`~gnn_mp_envs.core.planners.RRT` / :class:`~gnn_mp_envs.core.planners.BiRRT` ``.step``,
sample after sample, in the same order and arithmetic (the Python planner stays the reference: the tests
grow both trees from the same samples and compare them node for node): nearest node
(:mod:`~gnn_mp_envs.core.nearest`, the scan's answer), steer and check (the problem's compiled kernel),
add, then RRT's goal test and goal connection or BiRRT's connect and swap. It stops after the sample
that solves the problem or fills the tree, or when the iteration budget is spent, and says how many
samples it consumed; the caller builds the solution's path and updates the observation from the
nodes the loop appended.

A problem offers the loop by a :class:`CompiledKernel` (``problem.compiled_kernel``): three compiled
functions and their context. ``steer(a, target, step, ctx, x_new, distance)`` steers from ``a`` toward
``target`` by at most ``step`` into ``x_new``, writes ``|target - a|`` (the problem's arithmetic) to
``distance[0]`` and checks the edge: ``r > 0`` free after ``r`` collision checks, ``r < 0`` blocked
after ``-r``; below :data:`~gnn_mp_envs.core.problem.ZERO_LENGTH` the motion is refused unchecked (``r``
is not read). ``motion(a, b, ctx)`` checks the edge ``a -> b`` the same way. ``goal_distance(a, b)`` is
the problem's distance of the goal connection (its cost and its ``step`` test). The loop is compiled
once per kernel (its ``tag``), with these three bound into it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from gnn_mp_envs.core.nearest import IndexArrays, index_insert, index_nearest
from gnn_mp_envs.core.problem import ZERO_LENGTH
from gnn_mp_envs.utils.array_groups import GroupTable, array_group
from gnn_mp_envs.utils.compiled import jit, specialized

#: The loop's planners.
RRT_LOOP, BIRRT_LOOP = 0, 1
#: ``result`` entries: samples consumed, solved (0/1), and the nodes the solution meets at.
CONSUMED, SOLVED, MEET_A, MEET_B = 0, 1, 2, 3
#: ``counters`` entries the loop adds to: edges checked, collision checks.
EDGES, CHECKS = 0, 1
#: BiRRT's connect stops on a node this close to its target (the Python planner's test).
CONNECTED = 1e-9


#: The node store (:class:`~gnn_mp_envs.core.tree.TreeStore`'s arrays; ``size``: the node count, one entry;
#: ``nodes_in``: per search tree).
TreeArrays = array_group("TreeArrays", (("states", np.float64, 2), ("parent", np.int64, 1), ("cost", np.float64, 1),
                                        ("tree_id", np.int64, 1), ("size", np.int64, 1), ("nodes_in", np.int64, 1)))
#: The problem's goal and the loop's scratch and answers (``counters``: :data:`EDGES`, :data:`CHECKS`;
#: ``result``: :data:`CONSUMED` ... :data:`MEET_B`).
LoopArrays = array_group("LoopArrays", (("goal", np.float64, 1), ("x_new", np.float64, 1), ("distance", np.float64, 1),
                                        ("counters", np.int64, 1), ("result", np.int64, 1)))
#: The loop's table (:mod:`gnn_mp_envs.utils.array_groups`): one argument for every array of a planner (the
#: exact k-d index's: :class:`~gnn_mp_envs.core.nearest.IndexArrays`).
LAYOUT = GroupTable("loop", (TreeArrays, IndexArrays, LoopArrays))
view_tree = LAYOUT.viewer(TreeArrays)
view_index = LAYOUT.viewer(IndexArrays)
view_loop = LAYOUT.viewer(LoopArrays)


@dataclass(frozen=True)
class CompiledKernel:
    """What a problem gives the compiled loop: its compiled steer, edge check and goal distance, the
    context they read (arrays or a tuple of them), and a tag naming the kind (one compiled loop each)."""

    tag: str
    steer: Callable
    motion: Callable
    goal_distance: Callable
    context: Any


@jit(inline=True)
def _add(state, parent, tree, cost, t, ix):
    """Append a node (the node store's ``add`` and the k-d tree's insertion); its index."""
    i = t.size[0]
    for c in range(t.states.shape[1]):
        t.states[i, c] = state[c]
    t.parent[i] = parent
    t.cost[i] = (t.cost[parent] if parent >= 0 else 0.0) + cost
    t.tree_id[i] = tree
    t.size[0] = i + 1
    t.nodes_in[tree] += 1
    index_insert(i, tree, t.states, ix)
    return i


@jit(inline=True)
def next_tree(extended, other, sizes, balance):
    """BiRRT's tree for the next sample after one that extended ``extended``: the ``other`` (they alternate),
    unless ``balance`` and the other holds at least twice as many nodes (``sizes``: nodes per tree): then the
    smaller one again (VAMP's balanced RRT-Connect, tree ratio 1). The one place this rule is written."""
    if balance and sizes[other] >= 2 * sizes[extended]:
        return extended
    return other


@jit(inline=True)
def _nearest(x, tree, t, ix):
    return index_nearest(x, tree, ix)[0]


def _plan(samples, planner, active, budget, step, goal_tolerance, balance, table, context):
    """Consume ``samples`` in order (at most ``budget`` of them) as the Python planner's ``step``, on the
    arrays of ``table`` (:data:`LAYOUT`); the loop's ``result``: samples consumed, solved, meeting nodes.
    ``balance``: BiRRT's trees are balanced (:func:`next_tree`). Returns the active tree after the last sample."""
    t, ix, lp = view_tree(table), view_index(table), view_loop(table)
    states, size, goal, x_new, distance, counters, result = t.states, t.size, lp.goal, lp.x_new, lp.distance, \
        lp.counters, lp.result
    capacity = states.shape[0]
    result[CONSUMED], result[SOLVED], result[MEET_A], result[MEET_B] = 0, 0, -1, -1
    for s in range(min(samples.shape[0], budget)):
        if s > 0 and size[0] >= capacity:            # the tree filled up: the episode ends there
            break
        result[CONSUMED] = s + 1
        a = active if planner == BIRRT_LOOP else 0
        # ---- extend tree a toward the sample
        i = -1
        if size[0] < capacity:
            near = _nearest(samples[s], a, t, ix)
            r = _steer(states[near], samples[s], step, context, x_new, distance)   # noqa: F821 (bound per kernel)
            if distance[0] >= ZERO_LENGTH:
                counters[EDGES] += 1
                counters[CHECKS] += abs(r)
                if r > 0:
                    d = distance[0]
                    i = _add(x_new, near, a, d if d <= step else step, t, ix)
        if planner == RRT_LOOP:
            if i < 0:
                continue
            x = states[i]
            acc = 0.0
            for c in range(x.shape[0]):
                acc += (x[c] - goal[c]) * (x[c] - goal[c])
            if not math.sqrt(acc) <= goal_tolerance:
                if size[0] >= capacity:
                    continue
                d = _goal_distance(goal, x)                                  # noqa: F821
                if d > step:
                    continue
                r = _motion(x, goal, context)                                # noqa: F821
                counters[EDGES] += 1
                counters[CHECKS] += abs(r)
                if r < 0:
                    continue
                i = _add(goal, i, 0, d, t, ix)
            result[SOLVED], result[MEET_A] = 1, i
            return active
        # ---- BiRRT: connect the other tree toward the new node, then swap
        b = 1 - a
        if i >= 0:
            target = states[i]                                               # a node's row never changes
            near = _nearest(target, b, t, ix)
            while True:
                acc = 0.0
                for c in range(target.shape[0]):                             # the scan's distance to ``near``
                    v = (states[near, c] - target[c]) * ix.weights[c]
                    acc += v * v
                if math.sqrt(acc) < CONNECTED:
                    result[SOLVED], result[MEET_A], result[MEET_B] = 1, i, near
                    return b                    # solved: the other tree (the caller reads the extended one off it)
                if size[0] >= capacity:
                    break
                r = _steer(states[near], target, step, context, x_new, distance)    # noqa: F821
                if distance[0] < ZERO_LENGTH:
                    break
                counters[EDGES] += 1
                counters[CHECKS] += abs(r)
                if r < 0:
                    break
                d = distance[0]
                near = _add(x_new, near, b, d if d <= step else step, t, ix)
        active = next_tree(a, b, t.nodes_in, balance)
    return active


def compiled_loop(kernel: CompiledKernel) -> Callable:
    """The loop with ``kernel``'s functions bound in (compiled on its first call; one per tag)."""
    return specialized(_plan, kernel.tag, _steer=kernel.steer, _motion=kernel.motion,
                       _goal_distance=kernel.goal_distance)
