"""Arrays handed to compiled code as one table of addresses: groups of arrays (namedtuples) that compiled
functions view without reference counts.

A compiled call that takes dozens of arrays pays for each at the call (numba types and unboxes every
argument) and, reading them from an object, an atomic reference count increment and decrement per
array; for the sphere checker's kernel that was a fifth of its time. Here the arrays are grouped
(:func:`array_group`: a namedtuple whose ``spec`` names each field's dtype and dimensions), a
:class:`GroupTable` lays out a few groups, :meth:`GroupTable.pack` writes one int64 table of their
addresses and shapes (refusing an array of another dtype, dimension count or layout in one line), and
the compiled viewers (:meth:`GroupTable.viewer`, generated from the spec: no hand-kept order to drift)
turn the table back into the namedtuple of arrays, as :func:`numba.carray` views. The arrays must
outlive the table: keep them with it, and pack again after replacing one.
"""

from __future__ import annotations

import sys
from collections import namedtuple
from typing import Any

import numpy as np
from numba import carray, types
from numba.core.extending import intrinsic

from gnn_mp_envs.utils.compiled import jit


def array_group(name: str, fields: tuple[tuple[str, Any, int], ...]) -> type:
    """A namedtuple of arrays with a ``spec``: per field its name, dtype and number of dimensions (a class
    of the calling module, where it must be bound to ``name``: pickle finds it there)."""
    cls = namedtuple(name, [field for field, _, _ in fields], module=sys._getframe(1).f_globals["__name__"])
    cls.spec = tuple((field, np.dtype(dtype), ndim) for field, dtype, ndim in fields)
    return cls


@intrinsic
def _voidptr(typingctx, address):
    """The int64 ``address`` as a ``void*`` (for :func:`numba.carray`)."""
    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(types.voidptr))

    return types.voidptr(types.int64), codegen


@jit(inline=True)
def _view1(table, g, i, dtype):
    """Field ``i`` of group ``g`` of a table as the 1-D array it describes (scalars read: no view of the
    table, no reference count)."""
    return carray(_voidptr(table[g, i, 0]), (table[g, i, 1],), dtype)


@jit(inline=True)
def _view2(table, g, i, dtype):
    return carray(_voidptr(table[g, i, 0]), (table[g, i, 1], table[g, i, 2]), dtype)


@jit(inline=True)
def _view3(table, g, i, dtype):
    return carray(_voidptr(table[g, i, 0]), (table[g, i, 1], table[g, i, 2], table[g, i, 3]), dtype)


class GroupTable:
    """The layout of a table: ``groups`` (classes of :func:`array_group`) in order; ``name`` names its
    viewers (``view_<name>_<group>``, and so their cache files)."""

    def __init__(self, name: str, groups: tuple[type, ...]) -> None:
        self.name = name
        self.groups = groups
        self.max_fields = max(len(group.spec) for group in groups)
        self._describers = tuple(self._describer(group) for group in groups)
        #: The compiled function of :meth:`pack` (all the groups' arrays in one call), made on the first pack.
        self.whole_describer: Any = None
        self._whole: Any = None

    def pack(self, instances: tuple) -> np.ndarray:
        """The table of ``instances`` (one of each group, in order): per array its address and shape.

        One compiled call for the whole table (:meth:`_whole_describer`), compiled for the exact array types
        of the groups' specs only, so numba's dispatch checks every array in C; arrays of any other type
        (dtype, dimensions, layout, read-only) take the checked path, which refuses a wrong one in one line."""
        if tuple(map(type, instances)) == self.groups:
            describe = self._whole or self._whole_describer()
            try:
                return describe(*instances)
            except TypeError:               # not exactly the spec's array types: the checked path says which
                pass
        return self._checked_pack(instances)

    def _checked_pack(self, instances: tuple) -> np.ndarray:
        """:meth:`pack` with each group and array checked in Python (one line naming the first wrong one)."""
        table = np.zeros((len(self.groups), self.max_fields, 4), dtype=np.int64)
        for g, (cls, group) in enumerate(zip(self.groups, instances, strict=True)):
            if type(group) is not cls:
                raise TypeError(f"the {self.name} table's group {g} must be a {cls.__name__}, "
                                f"got {type(group).__name__}")
            for array, (name, dtype, ndim) in zip(group, cls.spec, strict=True):
                if not (type(array) is np.ndarray and array.dtype == dtype and array.ndim == ndim
                        and array.flags.c_contiguous):
                    raise TypeError(f"the {self.name} table's {cls.__name__}.{name} must be a C-contiguous {ndim}-D "
                                    f"{dtype.name} array, got {getattr(array, 'dtype', type(array))} "
                                    f"{getattr(array, 'shape', '')}")
            self._describers[g](table, *group)
        return table

    def _whole_describer(self) -> Any:
        """A Python function of the groups calling one compiled function of all their arrays, which writes the
        whole table (a table per problem: one numba dispatch instead of one per group, and no Python test per
        array). The compiled function takes only the specs' C-contiguous, writable arrays (its one signature,
        loaded from numba's cache or compiled on the first pack; other types raise TypeError)."""
        from numba import from_dtype

        name = f"describe_{self.name}"
        arrays = [f"g{g}_{i}" for g, cls in enumerate(self.groups) for i in range(len(cls.spec))]
        lines = [f"def {name}({', '.join(arrays)}):",
                 f"    table = np.zeros(({len(self.groups)}, {self.max_fields}, 4), dtype=np.int64)"]
        for g, cls in enumerate(self.groups):
            lines += _address_lines(g, cls, f"g{g}_")
        lines.append("    return table")
        compiled = _compiled(name, lines, {"np": np})
        compiled.compile(types.int64[:, :, ::1](*(types.Array(from_dtype(dtype), ndim, "C")
                                                  for cls in self.groups for _, dtype, ndim in cls.spec)))
        compiled.disable_compile()
        groups = ", ".join(f"g{g}" for g in range(len(self.groups)))
        spread = ", ".join(f"*g{g}" for g in range(len(self.groups)))
        caller: dict[str, Any] = {"compiled": compiled}
        exec(f"def describe({groups}):\n    return compiled({spread})\n", caller)
        self._whole, self.whole_describer = caller["describe"], compiled
        return self._whole

    def _describer(self, cls: type) -> Any:
        """The compiled function writing group ``cls``'s rows of a table: per array its address and shape, in
        one call: a compiled call per array would pay numba's dispatch once per array, and a planner packs its
        table for every problem it plans (a checker, every scene)."""
        name = f"describe_{self.name}_{cls.__name__.lower()}"
        args = ", ".join(f"a{i}" for i in range(len(cls.spec)))
        return _compiled(name, [f"def {name}(table, {args}):", *_address_lines(self.groups.index(cls), cls, "a")])

    def viewer(self, cls: type) -> Any:
        """The compiled (inlined) function viewing group ``cls`` of a table of this layout."""
        g = self.groups.index(cls)
        views = ", ".join(f"_view{ndim}(table, {g}, {i}, np.{dtype.name})"
                          for i, (_, dtype, ndim) in enumerate(cls.spec))
        name = f"view_{self.name}_{cls.__name__.lower()}"
        return _compiled(name, [f"def {name}(table):", f"    return {cls.__name__}({views})"],
                         {"np": np, "_view1": _view1, "_view2": _view2, "_view3": _view3, cls.__name__: cls},
                         inline=True)


def _address_lines(g: int, cls: type, prefix: str) -> list[str]:
    """The source lines writing group ``g``'s rows of a table (``cls``: its class): per array (named ``prefix``
    and its index) its address, then its shape."""
    lines = []
    for i, (_, _, ndim) in enumerate(cls.spec):
        lines.append(f"    table[{g}, {i}, 0] = {prefix}{i}.ctypes.data")
        lines.extend(f"    table[{g}, {i}, {1 + d}] = {prefix}{i}.shape[{d}]" for d in range(ndim))
    return lines


def _compiled(name: str, lines: list[str], names: dict[str, Any] | None = None, inline: bool = False) -> Any:
    """:func:`jit` of the function ``name`` that ``lines`` define (``names``: the globals it reads)."""
    namespace: dict[str, Any] = {"__name__": __name__, **(names or {})}    # numba's cache finds the module by it
    exec(compile("\n".join(lines) + "\n", __file__, "exec"), namespace)
    return jit(namespace[name], inline=inline)
