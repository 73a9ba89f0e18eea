"""Keep freed memory in the process for the next array, for commands that process a record whole.

``diagnose`` on a long record forms arrays of tens to hundreds of MB (a record's columns side by
side, 600,000 x 19 doubles = 91 MB on a 10-minute 1 kHz log), frees them and forms others of the
same size, dozens of times. glibc's ``malloc`` serves a block above its *mmap threshold* (128 KiB,
raised as blocks are freed up to 32 MiB) with a fresh mapping from the kernel and unmaps it on
``free``; a freed block at the top of the heap beyond the *trim threshold* is returned too. Either
way the next array is page-faulted in (and zeroed by the kernel) anew: on the 10-minute bench log
0.7-1.0 s of system time beside 1.8 s of user time (``docs/benchmarks.md``, session 9).

:func:`keep_freed_memory` raises both thresholds (``mallopt(3)``: ``M_MMAP_THRESHOLD``,
``M_TRIM_THRESHOLD``) so that freed blocks stay in the heap, where the next array reuses them; the
process then holds the memory of its largest moment until it exits. It also stops NumPy advising
the kernel to back every array of 4 MB or more with transparent huge pages (``madvise(2)``,
``MADV_HUGEPAGE``; NumPy's ``NUMPY_MADVISE_HUGEPAGE``, read only at import): on a kernel that
compacts memory to find a huge page at the fault (``/sys/kernel/mm/transparent_hugepage/defrag``
``madvise``, Debian's default) that advice costs more than it saves once arrays reuse memory that is
already mapped. Measured on the 10-minute bench log (``docs/benchmarks.md``, session 9):
system time 0.66-1.28 s by default, 0.43-1.02 s with the thresholds alone, 0.19-0.26 s with both.

That suits a command that reads a record, processes it and ends (``estimate``, ``diagnose``) and a
fleet worker's task (``track --manifest``: a worker tracks one log after another in blocks of the same
sizes; Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which made glibc return every
freed block and fault the next one in anew), not a long-running service whose peak is rare, and it is a
setting of the whole process: the library never calls it by itself. Elsewhere than glibc (macOS, musl, Windows) only
NumPy's advice is changed.
"""

from __future__ import annotations

import ctypes
import platform

import numpy as np

#: ``mallopt`` parameters (glibc's ``malloc.h``)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: blocks up to this size come from the heap (bytes)
MMAP_THRESHOLD_BYTES = 1 << 30
#: free memory at the top of the heap up to this size is kept (bytes)
TRIM_THRESHOLD_BYTES = 1 << 31


def keep_freed_memory() -> bool:
    """Set glibc's allocator to keep freed blocks for reuse, and NumPy to stop advising huge pages;
    True when the allocator was set (glibc), False elsewhere."""
    multiarray = getattr(getattr(np, "_core", None), "multiarray", None)
    no_huge_pages = getattr(multiarray, "_set_madvise_hugepage", None)  # what NUMPY_MADVISE_HUGEPAGE=0 sets at import
    if no_huge_pages is not None:
        no_huge_pages(False)
    if platform.libc_ver()[0] != "glibc":
        return False
    mallopt = getattr(ctypes.CDLL(None), "mallopt", None)
    if mallopt is None:
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )
