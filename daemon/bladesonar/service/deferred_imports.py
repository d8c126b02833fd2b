"""Modules the MQTT client imports but the daemon seldom or never uses, loaded on first use.

paho-mqtt imports ``ssl`` whether TLS is used or not (it reads it only when TLS is set
up, or in its socket code's ``except ssl.SSLWant...Error`` clauses, which are evaluated
only when a socket call raises) and ``urllib.request`` for proxy settings it reads only
when PySocks is installed; ``hashlib`` loads OpenSSL's libcrypto for hashes that Python
also has built in. Together they were 6.7 MiB of the daemon's resident memory.

A deferred module is a stand-in in ``sys.modules`` that imports the real one at the
first attribute it lacks, then takes on all of the real one's attributes (the same
objects: an exception raised by the real module is caught by ``except`` on the stand-in).
Not the standard library's ``importlib.util.LazyLoader``: its module loads at any
attribute access, and an ``import ssl`` statement elsewhere reads ``__spec__``, which
loaded it at once. Until then the ``ssl`` stand-in has the exception classes the client's
``except`` clauses name (``PLACEHOLDERS``) as classes nothing raises: its non-blocking
socket reads end in ``BlockingIOError`` many times a second, every one evaluating
``except ssl.SSLWantReadError`` first, and a plain socket never raises an SSL error. TLS
set up from the config loads the real ``ssl`` (in the main thread, before the client's
network thread exists), and its classes replace the placeholders before any SSL socket
exists. ``hashlib`` is told to use Python's own SHA-2 (the same digests) when the build
has it.

Call :func:`defer` before anything imports these modules; one already imported is left
as it is.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import threading
import types
from typing import Any

#: Deferred to their first use.
DEFERRED = ("ssl", "urllib.request")
#: Exception classes a stand-in has before the real module is loaded (see above): those
#: named in ``except`` clauses of paho-mqtt 2.x and of service/publish.py.
PLACEHOLDERS = {"ssl": ("SSLError", "SSLWantReadError", "SSLWantWriteError",
                        "CertificateError")}


class _NeverRaised(Exception):
    """Base of the placeholder exception classes: nothing raises them."""

_lock = threading.Lock()


class _Deferred(types.ModuleType):
    """Stands in for a module until an attribute it lacks is read."""

    def __getattr__(self, attr: str) -> Any:
        with _lock:
            name = self.__name__
            if self.__dict__.get("_deferred_real") is None:
                if sys.modules.get(name) is self:
                    del sys.modules[name]
                try:
                    real = importlib.import_module(name)
                except BaseException:
                    sys.modules.setdefault(name, self)
                    raise
                self.__dict__.update(real.__dict__)
                self.__dict__["_deferred_real"] = real
        if attr in self.__dict__:
            return self.__dict__[attr]
        raise AttributeError(f"module {self.__name__!r} has no attribute {attr!r}")


def defer_import(name: str) -> bool:
    """Put a stand-in for ``name`` into ``sys.modules``; True if it was deferred."""
    if name in sys.modules:
        return False
    spec = importlib.util.find_spec(name)
    if spec is None:
        return False
    module = _Deferred(name)
    module.__spec__ = spec
    module.__file__ = spec.origin
    for cls in PLACEHOLDERS.get(name, ()):
        setattr(module, cls, type(cls, (_NeverRaised,), {"__module__": __name__}))
    sys.modules[name] = module
    parent, _, child = name.rpartition(".")
    if parent:
        # ``import a.b`` finds a.b in sys.modules and binds it on a only when it loads it
        setattr(sys.modules[parent], child, module)
    return True


def builtin_hashes() -> bool:
    """Make ``hashlib`` use Python's built-in hashes instead of OpenSSL's (it falls back to
    them when ``_hashlib`` cannot be imported); only when the built-in SHA-2 is there, and
    before ``hashlib`` is imported. True if done."""
    if "hashlib" in sys.modules or "_hashlib" in sys.modules:
        return False
    if not any(importlib.util.find_spec(m) is not None for m in ("_sha2", "_sha256")):
        return False
    sys.modules["_hashlib"] = None        # type: ignore[assignment]  # "cannot import"
    return True


def loaded(name: str) -> bool:
    """Whether ``name`` is imported for real (not a stand-in still waiting)."""
    m = sys.modules.get(name)
    return m is not None and not (isinstance(m, _Deferred) and
                                  m.__dict__.get("_deferred_real") is None)


def defer() -> list[str]:
    """All of the above; the names deferred or replaced."""
    done = [n for n in DEFERRED if defer_import(n)]
    if builtin_hashes():
        done.append("_hashlib")
    return done
