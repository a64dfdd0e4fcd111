"""Process-level CPU settings for training and inference entry points (threads, allocator).

:func:`tune_cpu_allocator`: glibc returns every freed block above its mmap threshold (at most 32 MiB by
default) to the kernel, so each large temporary of a training step is page-faulted in again; measured on
the 2-core machine, one backbone forward + backward took 270-360 k minor faults and 0.7-0.9 s of kernel
time; the fitter's network pass (16 clouds of 500 points) 571 k faults and 1.3 s of kernel time per call
(benchmarks/bench_fit_network.py). Raising the threshold and the trim threshold keeps freed memory in the
process (peak memory is unchanged; the memory is reused). Called by ``arteq.train``, ``arteq.eval`` and
``arteq.fit.Fitter``. No-op where glibc's ``mallopt`` is unavailable or ``ARTEQ_MALLOC_TUNE=0``.

:func:`one_thread`: run a block with one intra-op thread (small per-sample ops; LAPACK results that must
not depend on the thread count), restoring the previous count.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
from collections.abc import Iterator


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """Run the block with ``torch.set_num_threads(1)``, then restore the previous thread count."""
    import torch

    threads = torch.get_num_threads()
    if threads != 1:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if threads != 1:
            torch.set_num_threads(threads)


_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3
_TUNED = False


def tune_cpu_allocator(threshold_bytes: int = 1 << 30) -> bool:
    """Keep large freed blocks in the process (glibc ``mallopt``); returns True if applied."""
    global _TUNED
    if _TUNED:
        return True
    if os.environ.get("ARTEQ_MALLOC_TUNE", "1") == "0" or os.name != "posix":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    v = int(min(threshold_bytes, 2**31 - 1))
    ok = all(mallopt(opt, v) == 1 for opt in (_M_MMAP_THRESHOLD, _M_TRIM_THRESHOLD, _M_TOP_PAD))
    _TUNED = ok
    return ok
