import os
import shutil
import tempfile

# Tests run on the CPU whatever the machine has, with a private compilation cache per session: programs compiled
# by other runs or other processes on this machine (a killed one may leave an entry half written) are never read,
# and spawned workers share the session's directory through the environment.
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
_SESSION_JAX_CACHE = None
if "PDESTREAM_JAX_CACHE" not in os.environ:
    _SESSION_JAX_CACHE = tempfile.mkdtemp(prefix="pdestream-test-jax-")  # mode 700: private, as the cache needs
    os.environ["PDESTREAM_JAX_CACHE"] = _SESSION_JAX_CACHE


def pytest_unconfigure(config):
    """Remove the session's compilation cache (only the directory this session made)."""
    if _SESSION_JAX_CACHE is not None and os.environ.get("PDESTREAM_JAX_CACHE") == _SESSION_JAX_CACHE:
        shutil.rmtree(_SESSION_JAX_CACHE, ignore_errors=True)
