import gc
import os
import sys

import pytest

# Tests run on the CPU whatever the machine has, and without JAX's persistent compilation cache: a warm cache
# saved little (13 min cold, about as long warm, on 2 loaded cores), and its size bound's eviction raced between
# the suite's processes (warnings of entries gone missing).
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
os.environ.setdefault("PDESTREAM_JAX_CACHE", "")
# No progress lines unless a test asks for them (tests/test_progress.py): on a loaded machine a command passes
# the Meter's first 3 s and prints one, and the checks that an error is one line would then depend on the load.
os.environ.setdefault("PDESTREAM_PROGRESS", "0")
os.environ.setdefault("PDESTREAM_PROGRESS_HISTORY", "")  # no record of measured times under ~/.cache


MAPPINGS_BEFORE_RELEASE = 30_000  # of Linux's default 65,530 per process (vm.max_map_count)


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after a test file once the process holds many memory mappings.

    Every compiled XLA CPU program keeps about three memory mappings of its own (code, constants, data), and the
    whole suite compiles more programs than Linux's default limit of 65,530 mappings per process allows: clean-clone
    runs died of a segfault inside XLA's compiler at ~92% of the suite (33,800 mappings at 15%). Dropping them
    only past a threshold keeps the programs that the next files would otherwise compile again.
    """
    yield
    jax = sys.modules.get("jax")
    if jax is not None and _mappings() > MAPPINGS_BEFORE_RELEASE:
        jax.clear_caches()
        gc.collect()


def _mappings() -> int:
    """This process's memory mappings (0 where /proc is not there)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


SLOW_TESTS = os.path.join(os.path.dirname(__file__), "slow_tests.txt")


@pytest.hookimpl(tryfirst=True)  # before xdist's, which reads the groups set here (--dist loadgroup)
def pytest_collection_modifyitems(config, items):
    # the measured long tests (slow_tests.txt) join the slow set, so the quick default stays a few minutes
    with open(SLOW_TESTS) as f:
        listed = {line.strip() for line in f if line.strip() and not line.startswith("#")}
    from pdestream import generator

    for item in items:
        if item.nodeid.split("@")[0] in listed:  # (xdist's loadgroup appends "@GROUP" to a grouped test's id)
            item.add_marker(pytest.mark.slow)
        # --dist loadgroup (CI): an entry's tests run in one worker, which compiles its programs once, not in each
        entry = getattr(getattr(item, "callspec", None), "params", {}).get("name")
        if isinstance(entry, str) and entry in generator.PDES:
            item.add_marker(pytest.mark.xdist_group(entry))


@pytest.fixture
def solver_settings():
    """External solvers: each test starts from the default settings (1 worker, no timeout) and leaves the
    environment as it found it (configure(), and so the CLI's --solver-workers / --solver-timeout, write
    os.environ). Test files that run external solvers use it for every test."""
    from pdestream.generator.external import solver as external

    names = (external.WORKERS_ENV, external.TIMEOUT_ENV)
    saved = {k: os.environ.pop(k, None) for k in names}
    yield
    for k, v in saved.items():
        os.environ.pop(k, None)
        if v is not None:
            os.environ[k] = v
