import os

# Tests run on the CPU whatever the machine has, without JAX's persistent compilation cache: two clean-clone runs
# of the whole suite died of a segfault inside JAX's cache serialisation (reading, then writing, the same
# program of tests/test_solver_oracle.py) although the file passes alone; the cache only saves compile time.
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
os.environ.setdefault("PDESTREAM_JAX_CACHE", "")
