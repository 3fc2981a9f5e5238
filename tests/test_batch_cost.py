"""benchmarks.batch_cost: the timed loop measures the batches it says (its figures are the benchmark's, not tested)."""

from benchmarks.batch_cost import route_ms


def test_route_ms_skips_the_warm_batches_and_runs_the_step_and_the_report_on_each():
    handed, reported, stepped = [], [], []

    def batches():
        i = 0
        while True:
            handed.append(i)
            yield i
            i += 1

    route, work = route_ms(batches(), 7, step=stepped.append, after_each=reported.append, skip=3)
    assert len(handed) == 10 and reported == stepped == list(range(10)) and route >= 0.0 and work >= 0.0
    route, work = route_ms(batches(), 2, skip=0)  # no step: the route alone
    assert len(handed) == 12 and route >= 0.0
