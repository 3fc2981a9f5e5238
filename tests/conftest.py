import os

# Tests run on the CPU whatever the machine has, with a private compilation cache per session.
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
