"""benchmarks.batch_cost: the timed loop measures the batches it says (its figures are the benchmark's, not tested)."""

from benchmarks.batch_cost import per_batch_ms


def test_per_batch_ms_skips_the_warm_batches_and_reports_after_each_measured_and_warm_one():
    handed, reported = [], []

    def batches():
        i = 0
        while True:
            handed.append(i)
            yield i
            i += 1

    ms = per_batch_ms(batches(), 7, after_each=reported.append, skip=3)
    assert len(handed) == 10 and reported == list(range(10)) and ms >= 0.0
