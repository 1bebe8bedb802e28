"""Tiny compiled helpers shared by every layer (numba), and the calls through which compiled code runs a
state manifold's compiled operations (``interfaces.CompiledStateOperations``)."""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.core import cgutils, errors
from numba.core.dispatcher import Dispatcher
from numba.extending import intrinsic


@njit(cache=True, nogil=True)
def same_point(a: np.ndarray, b: np.ndarray) -> bool:
    """Element-wise equality of two vectors of the same length (a cheap ``np.array_equal`` for hot paths)."""
    for i in range(a.shape[0]):  # noqa: SIM110 - an explicit loop compiles to a tight, early-exit loop
        if a[i] != b[i]:
            return False
    return True


@njit(cache=True, nogil=True)
def all_finite(values: np.ndarray) -> bool:
    """Whether every entry of the vector ``values`` is finite (``np.isfinite(values).all()`` without its
    temporary array of flags)."""
    for i in range(values.shape[0]):  # noqa: SIM110 - an explicit loop compiles to a tight, early-exit loop
        if not np.isfinite(values[i]):
            return False
    return True


@njit(cache=True, nogil=True)
def stack_columns(left: np.ndarray, right: np.ndarray, out: np.ndarray) -> None:
    """``out = [left | right]`` (same number of rows)."""
    n_left = left.shape[1]
    for i in range(out.shape[0]):
        for j in range(n_left):
            out[i, j] = left[i, j]
        for j in range(right.shape[1]):
            out[i, n_left + j] = right[i, j]


@njit(cache=True, nogil=True)
def stack_columns_left_multiplied(
    jacobian: np.ndarray, rows: int, left: np.ndarray, right: np.ndarray, out: np.ndarray
) -> None:
    """``out = J [left | right]`` where ``J`` is the identity except its leading ``rows x rows`` block
    (``jacobian``): the tangent map of a state difference whose non-Euclidean part comes first."""
    stack_columns(left, right, out)
    n_left = left.shape[1]
    columns = out.shape[1]
    row = np.empty(rows)
    for j in range(columns):
        for i in range(rows):
            total = 0.0
            for p in range(rows):
                total += jacobian[i, p] * (left[p, j] if j < n_left else right[p, j - n_left])
            row[i] = total
        for i in range(rows):
            out[i, j] = row[i]


# ------------------------------------------------------------------------- compiled calls through addresses
# A state manifold hands its compiled operations to compiled callers (the solver's kernels) as the addresses
# of numba-compiled functions (``interfaces.CompiledStateOperations``): integers, which cross from Python
# into a compiled call as fast as any argument, keep one compiled caller for every manifold and keep numba's
# disk cache working. (A numba function passed as an argument would do neither: its type carries the
# function's identity, which changes from one process to the next, so the caller would be compiled again in
# every process, and typing it on each call from Python costs microseconds.)

VECTOR = types.Array(types.float64, 1, "C")
"""A C-contiguous float64 vector: an argument type of the compiled state operations."""
MATRIX = types.Array(types.float64, 2, "C")
"""A C-contiguous float64 matrix."""
POINT_OPERATION = (VECTOR, VECTOR, VECTOR)
"""The arguments of ``integrate(x, dx, out)`` and ``difference(x0, x1, out)``."""
TRANSPORT_OPERATION = (VECTOR, VECTOR, MATRIX, MATRIX, MATRIX)
"""The arguments of ``transport_stacked(x0, x1, left, right, out)``."""


def compiled_address(function: Dispatcher, argument_types: tuple[types.Type, ...]) -> int:
    """The address of ``function`` (a numba ``njit`` function returning nothing) compiled for
    ``argument_types``, in numba's calling convention: what ``call_state_operation`` and
    ``call_state_transport`` call. Compiles that specialisation, or loads it from numba's cache, if it does
    not exist yet."""
    result = function.get_compile_result(types.void(*argument_types))
    return result.library.get_pointer_to_function(result.fndesc.llvm_func_name)


def _checked(argument: types.Type, expected: types.Array) -> types.Array:
    """``expected`` if ``argument`` is it (a writable C-contiguous float64 array of its dimension)."""
    if not (
        isinstance(argument, types.Array)
        and argument.dtype == types.float64
        and argument.ndim == expected.ndim
        and argument.layout == "C"
        and argument.mutable
    ):
        raise errors.TypingError(
            f"a compiled state operation takes writable C-contiguous {expected}, got {argument} "
            "(np.ascontiguousarray makes one)"
        )
    return expected


def _call_through_address(argument_types: tuple[types.Type, ...]):
    """The code generator of a call of the function at an address compiled for ``argument_types``."""

    def codegen(context, builder, signature, arguments):
        address, *values = arguments
        function_type = context.call_conv.get_function_type(types.void, argument_types)
        function = builder.inttoptr(address, function_type.as_pointer())
        status, _ = context.call_conv.call_function(builder, function, types.void, argument_types, values)
        with cgutils.if_unlikely(builder, status.is_error):
            context.call_conv.return_status_propagate(builder, status)
        return context.get_dummy_value()

    return codegen


@intrinsic
def call_state_operation(typingctx, address, a, b, out):
    """``integrate(a, b, out)`` or ``difference(a, b, out)`` of a manifold, at ``address``
    (``CompiledStateOperations.addresses``); compiled code only. The arrays must be writable, C-contiguous
    float64 vectors (checked when the caller compiles)."""
    wanted = tuple(_checked(t, e) for t, e in zip((a, b, out), POINT_OPERATION, strict=True))
    return types.void(types.intp, a, b, out), _call_through_address(wanted)


@intrinsic
def call_state_transport(typingctx, address, x0, x1, left, right, out):
    """``transport_stacked(x0, x1, left, right, out)`` of a manifold, at ``address``; as
    ``call_state_operation``."""
    arguments = (x0, x1, left, right, out)
    wanted = tuple(_checked(t, e) for t, e in zip(arguments, TRANSPORT_OPERATION, strict=True))
    return types.void(types.intp, *arguments), _call_through_address(wanted)


# ------------------------------------------------------------------------ the compiled operations of R^n
@njit(cache=True, nogil=True)
def euclidean_integrate(x: np.ndarray, dx: np.ndarray, out: np.ndarray) -> None:
    """``out = x + dx``."""
    for i in range(out.shape[0]):
        out[i] = x[i] + dx[i]


@njit(cache=True, nogil=True)
def euclidean_difference(x0: np.ndarray, x1: np.ndarray, out: np.ndarray) -> None:
    """``out = x1 - x0``."""
    for i in range(out.shape[0]):
        out[i] = x1[i] - x0[i]


@njit(cache=True, nogil=True)
def euclidean_transport_stacked(
    x0: np.ndarray, x1: np.ndarray, left: np.ndarray, right: np.ndarray, out: np.ndarray
) -> None:
    """``out = [left | right]`` (the Jacobian of ``x1 - x0`` w.r.t. ``x1`` is the identity)."""
    stack_columns(left, right, out)
