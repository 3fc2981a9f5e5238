"""pdestream.datasets: the torch side. Streams solver output into training, caches it to HDF5/Zarr,
and loads caches back; ``_bridge`` is the only module that touches JAX, and is private: code outside this package
(the CLI, surrogate) reaches the generator through the names exported here (``pde_from_config``, ``max_index``,
``param_domains``, ``sample_tensors``)."""

from ._bridge import max_index, param_domains, pde_from_config, sample_tensors
from .cache import WriteSummary, open_cache, write_cache
from .derived import flow_vorticity, vorticity
from .loader import CachedTrajectories
from .normalize import Normalization, compute_normalization
from .reservoir import Reservoir, ReservoirStream
from .solver import SolverOracle, SolverStep
from .stream import StreamLoader, TrajectoryStream, stream_loader
from .views import VIEWS, NextStep, Operator, SteadyOperator, Whole, collate, examples, for_sample, gather, make_view

__all__ = [
    "Normalization", "Reservoir", "max_index", "param_domains", "pde_from_config", "sample_tensors", "ReservoirStream", "SolverOracle", "SolverStep", "StreamLoader", "TrajectoryStream", "compute_normalization", "gather", "stream_loader",
    "CachedTrajectories", "WriteSummary", "flow_vorticity", "vorticity", "open_cache", "write_cache", "VIEWS", "NextStep", "Operator", "SteadyOperator", "Whole", "collate", "examples", "for_sample", "make_view"]
