"""Every catalog entry keeps its configuration, hash, description and redraws, its samples and drawn parameters
to reference_samples.RTOL, and a sample alone keeps the bits it has in a batch (tests/reference_samples.py recorded
them; rewrite them only for a deliberate change of the numerics, with generator.NUMERICS bumped). Sample bits
differ between machines (XLA compiles for the host's instruction set), so no digest of a field is compared."""

import json

import pytest

from pdestream import generator
from tests import reference_samples as ref

SAVED = json.loads(ref.PATH.read_text())


def test_the_reference_covers_the_catalog_and_the_numerics_revision():
    assert SAVED["numerics"] == generator.NUMERICS
    assert set(SAVED["entries"]) <= {*generator.PDES, *ref.WALLED}  # new entries may come; none of these may go


def _entries():
    """The recorded entries; the flows (10-30 s each: a warm-up of hundreds of projections) in the slow set."""
    slow = pytest.mark.slow
    return [pytest.param(n, marks=slow) if generator.GROUP.get(n) == "fluids" else n for n in sorted(SAVED["entries"])]


@pytest.mark.parametrize("name", _entries())
def test_entry_is_unchanged(name):
    got, want = ref.record(name), dict(SAVED["entries"][name])
    fingerprint, want_fingerprint = got.pop("fingerprint"), want.pop("fingerprint")
    assert got == want
    assert not ref.close(fingerprint, want_fingerprint), (fingerprint, want_fingerprint)


@pytest.mark.parametrize("name", sorted(SAVED["dynamics"]))
def test_solve_and_advance_are_unchanged(name):
    got, want = ref.record_dynamics(name), SAVED["dynamics"][name]
    assert got["finite"] == want["finite"]
    for key in ("solve", "advance"):
        assert not ref.close(got[key], want[key]), (key, got[key], want[key])
