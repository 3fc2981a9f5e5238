"""The worker process of external solvers (generator.external.solver): ``python -m pdestream.generator.external.worker``."""

from .solver import _serve

if __name__ == "__main__":
    _serve()
