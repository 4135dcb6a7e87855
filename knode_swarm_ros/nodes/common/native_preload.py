"""Load a package's big native libraries with the GIL released, so a signal is handled at once.

Python runs a signal handler only when the main thread is back in the interpreter; importing
torch spends one long native call with the GIL held in ``dlopen`` of libtorch (0.45-0.8 s on
an idle 2-core VM, several times that under load), during which Ctrl-C or SIGTERM cannot be
seen. Here a worker thread ``dlopen``s those libraries through ctypes (a foreign call releases
the GIL) while the main thread waits in ``join`` with a timeout, where the handler runs and may
raise to abandon the start-up. The later ``import torch`` finds the libraries loaded (dlopen of
a loaded library returns its handle); what remains of it is interpreter work, interruptible
between bytecodes. A failed ``dlopen`` is ignored: the real import then does the same work and
reports any error itself.
"""

from __future__ import annotations

import ctypes
import glob
import os
import sys
import threading
from contextlib import contextmanager
from importlib.abc import MetaPathFinder
from importlib.util import find_spec
from typing import List, Sequence, Tuple

__all__ = ['preload_native', 'native_libraries', 'preloading']

# (glob inside the package folder, dlopen flags) in the order the package's import loads them:
# torch/__init__.py loads lib/libtorch_global_deps.so RTLD_GLOBAL, then imports _C (RTLD_NOW,
# Python's default flags), which pulls in libtorch_python, libtorch_cpu and libc10.
_LIBRARIES = {
    'torch': (('lib/libtorch_global_deps.so', os.RTLD_NOW | os.RTLD_GLOBAL), ('_C.*.so', os.RTLD_NOW)),
}


def native_libraries(package: str) -> List[Tuple[str, int]]:
    """``[(path, flags)]`` to preload for ``package`` (empty: unknown, not installed, or imported)."""
    if package in sys.modules or package not in _LIBRARIES:
        return []
    try:
        spec = find_spec(package)  # a top-level package: finds it without importing it
    except (ImportError, ValueError):
        return []
    if spec is None or not spec.submodule_search_locations:
        return []
    root = list(spec.submodule_search_locations)[0]
    return [
        (path, flags)
        for pattern, flags in _LIBRARIES[package]
        for path in sorted(glob.glob(os.path.join(root, pattern)))
    ]


def _dlopen_all(libraries: Sequence[Tuple[str, int]]) -> None:
    dlopen = ctypes.CDLL(None).dlopen
    dlopen.restype = ctypes.c_void_p
    dlopen.argtypes = [ctypes.c_char_p, ctypes.c_int]
    for path, flags in libraries:
        dlopen(os.fsencode(path), flags)  # NULL on failure: the import reports it


def preload_native(packages: Sequence[str]) -> None:
    """Load the native libraries of ``packages`` (known ones: torch) in a worker thread; wait
    for it in slices so that the main thread's signal handlers run meanwhile (and may raise)."""
    libraries = [lib for package in packages for lib in native_libraries(package)]
    if not libraries:
        return
    worker = threading.Thread(target=_dlopen_all, args=(libraries,), name='native-preload', daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(0.05)


class _PreloadFinder(MetaPathFinder):
    """Preloads a known package's libraries when it is first imported, then lets the usual
    finders import it (finds nothing itself)."""

    def __init__(self, packages: Sequence[str]):
        self.pending = set(packages)

    def find_spec(self, fullname, path=None, target=None):
        if fullname in self.pending:
            self.pending.discard(fullname)
            preload_native([fullname])
        return None


@contextmanager
def preloading(packages: Sequence[str] = tuple(_LIBRARIES)):
    """Within: the first import of each of ``packages`` preloads its native libraries
    (:func:`preload_native`), so only what is really imported is loaded."""
    finder = _PreloadFinder(packages)
    sys.meta_path.insert(0, finder)
    try:
        yield
    finally:
        sys.meta_path.remove(finder)
