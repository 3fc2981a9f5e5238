"""pdestream.datasets: the torch side. Streams solver output into training, caches it to HDF5/Zarr,
and loads caches back; ``_bridge`` is the only module that touches JAX."""

from .views import VIEWS, NextStep, Operator, Whole, collate, examples, make_view

__all__ = ["VIEWS", "NextStep", "Operator", "Whole", "collate", "examples", "make_view"]
