"""The numerics revision behind a sample's bits is recorded in every cache and compared on --resume, so a cache is
never finished with samples computed by other numerics (e.g. another ETDRK4 coefficient formula)."""

import pytest
from test_data_safety import digest, generate
from test_formats import FORMATS, _full_disk, _set_attr, one_line_error

from pdestream import datasets, generator


@pytest.mark.parametrize("suffix", FORMATS)
def test_a_cache_records_the_numerics_and_resume_refuses_other_numerics(tmp_path, capsys, monkeypatch, suffix):
    path = tmp_path / f"part.{suffix}"
    _full_disk(monkeypatch, after=1)  # an incomplete cache: one block of two written
    assert generate(capsys, path, "--block", 2)[0] == 2
    monkeypatch.undo()
    assert datasets.open_cache(path).attrs["pdestream_numerics"] == generator.NUMERICS
    _set_attr(path, "pdestream_numerics", generator.NUMERICS - 1)  # as an older pdestream wrote it
    sha = digest(path)
    code, _, err = generate(capsys, path, "--block", 2, "--resume")
    one_line_error(code, err, f"numerics: cache {generator.NUMERICS - 1} vs asked {generator.NUMERICS}")
    assert digest(path) == sha
