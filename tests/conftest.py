import gc
import os
import sys

import pytest

# Tests run on the CPU whatever the machine has, and without JAX's persistent compilation cache (a clean clone
# has nothing to reuse; the cache only saves compile time).
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
os.environ.setdefault("PDESTREAM_JAX_CACHE", "")


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after each test file.

    Every compiled XLA CPU program keeps about three memory mappings of its own (code, constants, data), and the
    whole suite compiles more programs than Linux's default limit of 65530 mappings per process allows: clean-clone
    runs died of a segfault inside XLA's compiler at ~92% of the suite (the mapping count was 33,800 at 15%).
    """
    yield
    jax = sys.modules.get("jax")
    if jax is not None:
        jax.clear_caches()
        gc.collect()
