"""MuJoCo's C functions for kernels: the few the IK cycle calls, declared for numba.

Why: from Python each MuJoCo call goes through the binding (argument checks, array conversions:
~1-2 us here); a kernel calls the C function directly, so a whole IK step (kinematics, Jacobians,
narrow phases and the math between them) can be one compiled call. The functions are MuJoCo's
own, so the numbers are the binding's to the bit (``tests/test_mujoco_c.py``).

Importing this module loads ``libmujoco`` (the one the ``mujoco`` package ships) into the process's
symbol table, so kernels that call these functions compile, and load from numba's on-disk cache,
once it is imported (every kernel module using them imports it first).

In a kernel: ``mj_kinematics(address(model_address), address(data_address))`` with the ints
``model._address`` / ``data._address`` (the structs stay where MuJoCo allocated them for the
objects' lifetime), and ``doubles(array)`` for a C-contiguous float64 array's data.
Signatures as in ``mujoco/include/mujoco/mujoco.h`` (mjtNum is double, int is int32).
"""

from __future__ import annotations

import glob
import os
from collections.abc import Mapping, Sequence

import llvmlite.binding as llvm
import mujoco
import numba
import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from servo_app.jit import kernel

# The MuJoCo major versions whose C signatures (below) and numbers (tests/test_mujoco_c.py,
# tests/test_diffik_equivalence.py) have been checked. A kernel calls a C function as declared here, with no
# binding in between to notice a changed signature: an unchecked major version is refused at import.
SUPPORTED_MAJOR = (3,)


def check_version(version: str) -> None:
    """Raise ImportError unless MuJoCo ``version`` is of a major version the kernels were checked with."""
    major = version.split(".", 1)[0]
    if not (major.isdigit() and int(major) in SUPPORTED_MAJOR):
        raise ImportError(
            f"mujoco {version} is installed, but servo_app's compiled IK calls MuJoCo's C functions as version "
            f"{'/'.join(map(str, SUPPORTED_MAJOR))}.x declares them; install a supported one "
            f"(./scripts/install does: pip install 'mujoco>=3.1,<4')")


check_version(mujoco.__version__)


def library_path() -> str:
    """The ``libmujoco.so.VERSION`` of the installed ``mujoco`` package: the library its binding uses,
    not another version an upgrade or a downgrade left beside it."""
    here = os.path.dirname(mujoco.__file__)
    exact = os.path.join(here, f"libmujoco.so.{mujoco.__version__}")
    if os.path.exists(exact):
        return exact
    found = sorted(glob.glob(os.path.join(here, "libmujoco.so*")))
    if len(found) == 1:
        return found[0]
    raise ImportError(f"mujoco {mujoco.__version__}: expected {exact}, found {found or 'no libmujoco.so*'}; "
                      f"reinstall it (pip install --force-reinstall 'mujoco>=3.1,<4')")


llvm.load_library_permanently(library_path())

_PTR = types.voidptr
_DOUBLES = types.CPointer(types.float64)

# void mj_kinematics(const mjModel* m, mjData* d)
mj_kinematics = types.ExternalFunction("mj_kinematics", types.void(_PTR, _PTR))
# void mj_comPos(const mjModel* m, mjData* d)
mj_comPos = types.ExternalFunction("mj_comPos", types.void(_PTR, _PTR))
# void mj_makeConstraint(const mjModel* m, mjData* d)
mj_makeConstraint = types.ExternalFunction("mj_makeConstraint", types.void(_PTR, _PTR))
# void mj_jacSite(const mjModel* m, const mjData* d, mjtNum* jacp, mjtNum* jacr, int site)
mj_jacSite = types.ExternalFunction("mj_jacSite", types.void(_PTR, _PTR, _DOUBLES, _DOUBLES, types.int32))
# void mju_mat2Quat(mjtNum quat[4], const mjtNum mat[9])
mju_mat2Quat = types.ExternalFunction("mju_mat2Quat", types.void(_DOUBLES, _DOUBLES))
# void mju_rotVecQuat(mjtNum res[3], const mjtNum vec[3], const mjtNum quat[4])
mju_rotVecQuat = types.ExternalFunction("mju_rotVecQuat", types.void(_DOUBLES, _DOUBLES, _DOUBLES))
# mjtNum mj_geomDistance(const mjModel* m, mjData* d, int geom1, int geom2, mjtNum distmax, mjtNum fromto[6])
mj_geomDistance = types.ExternalFunction(
    "mj_geomDistance", types.float64(_PTR, _PTR, types.int32, types.int32, types.float64, _DOUBLES))


@intrinsic
def address(typingctx, value):  # type: ignore[no-untyped-def]
    """The int ``value`` (a struct's ``_address``) as a ``void*``."""
    if not isinstance(value, types.Integer):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.inttoptr(args[0], cgutils.voidptr_t)

    return types.voidptr(value), codegen


@intrinsic
def doubles(typingctx, array):  # type: ignore[no-untyped-def]
    """A C-contiguous float64 array's data as ``double*`` (what MuJoCo's ``mjtNum*`` arguments take)."""
    if not (isinstance(array, types.Array) and array.dtype == types.float64 and array.layout == "C"):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return context.make_array(signature.args[0])(context, builder, args[0]).data

    return _DOUBLES(array), codegen


def _pointer_intrinsic(dtype: types.Type):  # type: ignore[no-untyped-def]
    @intrinsic
    def pointer(typingctx, value):  # type: ignore[no-untyped-def]
        if not isinstance(value, types.Integer):
            return None

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            return builder.inttoptr(args[0], context.get_value_type(signature.return_type))

        return types.CPointer(dtype)(value), codegen

    return pointer


# An int (an array's ``ctypes.data``) as a typed pointer, for ``numba.carray``: a kernel can then reach
# arrays through a table of addresses instead of taking each as an argument (numba's dispatch types
# and unboxes every argument: ~60 ns each in a tight loop, several times that with cold caches).
float64_pointer = _pointer_intrinsic(types.float64)
int64_pointer = _pointer_intrinsic(types.int64)
boolean_pointer = _pointer_intrinsic(types.boolean)
uint8_pointer = _pointer_intrinsic(types.uint8)


# The readers of such a table (made by address_table): row ``k`` as the array it points to.
@kernel("float64[::1](int64[:, ::1], int64)")
def table_f1(table: np.ndarray, k: int) -> np.ndarray:
    return numba.carray(float64_pointer(table[k, 0]), (table[k, 1],))


@kernel("float64[:, ::1](int64[:, ::1], int64)")
def table_f2(table: np.ndarray, k: int) -> np.ndarray:
    return numba.carray(float64_pointer(table[k, 0]), (table[k, 1], table[k, 2]))


@kernel("int64[::1](int64[:, ::1], int64)")
def table_i1(table: np.ndarray, k: int) -> np.ndarray:
    return numba.carray(int64_pointer(table[k, 0]), (table[k, 1],))


@kernel("int64[:, ::1](int64[:, ::1], int64)")
def table_i2(table: np.ndarray, k: int) -> np.ndarray:
    return numba.carray(int64_pointer(table[k, 0]), (table[k, 1], table[k, 2]))


@kernel("boolean[::1](int64[:, ::1], int64)")
def table_b1(table: np.ndarray, k: int) -> np.ndarray:
    return numba.carray(boolean_pointer(table[k, 0]), (table[k, 1],))


@kernel("uint8[::1](int64[:, ::1], int64)")
def table_u1(table: np.ndarray, k: int) -> np.ndarray:
    return numba.carray(uint8_pointer(table[k, 0]), (table[k, 1],))


_TABLE_KINDS = {"f": np.dtype(np.float64), "i": np.dtype(np.int64), "b": np.dtype(np.bool_), "u": np.dtype(np.uint8)}


def address_table(layout: Sequence[tuple[str, str, int]], arrays: Mapping[str, np.ndarray]) -> np.ndarray:
    """The table of ``arrays`` in ``layout``'s order ((name, kind, dimensions) per row; kind f float64,
    i int64, b bool, u uint8): row k is the array's ``ctypes.data``, then its shape. Each array must be
    of its kind and C-contiguous (TypeError otherwise); the caller keeps them alive as long as the table."""
    table = np.zeros((len(layout), 3), dtype=np.int64)
    for k, (name, kind, ndim) in enumerate(layout):
        a = arrays[name]
        if a.dtype != _TABLE_KINDS[kind] or a.ndim != ndim or not a.flags.c_contiguous:
            raise TypeError(f"{name}: {a.dtype}, {a.ndim} dims, not {kind} {ndim} C-contiguous")
        table[k] = (a.ctypes.data, a.shape[0], a.shape[1] if ndim == 2 else 0)
    return table
