"""Compiled (numba) kernels: the fast backend of the simulator, the batch engine and ``Controller``.

They implement the same equations as the NumPy reference (``model``, ``estimator``, ``control``,
``sim``) for one vehicle at a time with no heap allocation on the hot path; ``tests/test_compiled.py``
proves the two agree. Kernels are compiled on first use and cached on disk.

Numba keys each cached function on its own source file only, so a kernel that inlines code from
another module could load stale machine code after that module changed (an upgrade, an edit). Before
any kernel is imported, :func:`_refresh_cache` stamps the package's cache folder with
:func:`~vtol_impedance.io.source_digest` of every source the kernels read (and the package version) and
clears the cached kernels when it differs.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..io import source_digest
from . import jit  # noqa: F401  first: numba's vector width is set before anything defines a kernel (jit._wide_vectors)

_HERE = Path(__file__).resolve().parent
_SOURCES = (
    *sorted(_HERE.glob("*.py")),
    _HERE.parent / "conventions.py",
    _HERE.parent / "model" / "vehicle.py",  # MAX_ROTORS
    _HERE.parent / "records.py",  # LOG_ROW, failure limits
)


def _refresh_cache() -> None:
    """Clear the cached kernels when their sources changed. Safe when many processes import at once
    (sweep workers): the check-and-clear runs under an exclusive ``flock``, the stamp is written
    atomically, and processes of the same installation agree on the digest, so only the first one to
    see a new digest clears the cache, before anyone has loaded from it."""
    if os.environ.get("NUMBA_CACHE_DIR"):  # a user-managed cache: leave it alone
        return
    import fcntl

    digest = source_digest(_SOURCES)
    cache = _HERE / "__pycache__"
    stamp = cache / "kernels.stamp"
    try:
        if stamp.exists() and stamp.read_text() == digest:
            return
        cache.mkdir(exist_ok=True)
        with open(cache / "kernels.lock", "a+") as lock:
            fcntl.flock(lock.fileno(), fcntl.LOCK_EX)
            if stamp.exists() and stamp.read_text() == digest:
                return  # another process refreshed it while we waited
            for f in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
                f.unlink(missing_ok=True)
            tmp = cache / f"kernels.stamp.{os.getpid()}"
            tmp.write_text(digest)
            os.replace(tmp, stamp)
    except OSError:  # read-only install: numba falls back to its own cache location
        pass


_refresh_cache()


def kernels_cached() -> bool:
    """Whether the closed-loop kernel is in the on-disk cache (else the first run compiles: about two minutes
    on two cores, the README says how it was measured)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return True  # unknown layout: assume the user manages it
    return any((_HERE / "__pycache__").glob("engine.run_block-*.nbi"))
