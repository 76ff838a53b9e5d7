"""Fused multiply-add for numba kernels: a * b + c rounded once (LLVM's fma), whatever LLVM would contract or not,
so a kernel can reproduce the rounding of a BLAS that computes the same sums with FMA instructions."""

from __future__ import annotations

from typing import Any

from numba import types
from numba.extending import intrinsic


def _fma_in(float_type: types.Float) -> Any:
    """The fma intrinsic of one float type (its three arguments are cast to it)."""

    @intrinsic
    def fma(typingctx: object, a: types.Type, b: types.Type, c: types.Type) -> tuple:
        def codegen(context, builder, signature, args):
            return builder.fma(*args)

        return float_type(float_type, float_type, float_type), codegen

    return fma


fma32 = _fma_in(types.float32)
fma64 = _fma_in(types.float64)
