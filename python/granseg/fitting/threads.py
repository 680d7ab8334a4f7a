"""One BLAS thread while a campaign is fitted.

The fits' linear algebra is thousands of small products of tall, thin blocks
(residuals and Jacobians of ~10^5 rows and a handful of columns, their Gram
matrices, the trust-region steps). OpenBLAS splits each of them over every
core and wakes its threads for every call; on 2 cores, while the core's rayon
threads (or any other job) also want them, the waking costs more than the
products. Measured on the 16-experiment catalogue diagnosis with the machine
shared: 22.6 s with OpenBLAS's default threads, 11.9 s with one
(``OPENBLAS_NUM_THREADS=1``, BENCHMARKS.md "Diagnosis"). threadpoolctl (a
scikit-learn dependency) sets the limit for the call and restores it after.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

# scipy's own OpenBLAS (apart from numpy's) is loaded with scipy.linalg, and threadpoolctl limits
# only the libraries loaded when the limit is set: the fitting layer imports scipy inside its
# functions (granseg.fitting, on import time), so the first fit would otherwise run unlimited
import scipy.linalg  # noqa: F401
from threadpoolctl import threadpool_limits

__all__ = ["one_blas_thread"]

F = TypeVar("F", bound=Callable[..., Any])


def one_blas_thread(fn: F) -> F:
    """Run ``fn`` with the BLAS libraries limited to one thread (restored afterwards)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
