"""The worker process of external solvers (generator.external): ``python -m generator._solver_worker``."""

from generator.external import _serve

if __name__ == "__main__":
    _serve()
