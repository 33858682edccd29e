"""eve3d.core.timing: a stage's phases, on a clock the test sets."""
import pytest

from eve3d.core import timing


@pytest.fixture
def clock(monkeypatch):
    """perf_counter under the test's control; the process 'started' 2 s before the first phase."""
    now = [100.0]
    monkeypatch.setattr(timing.time, "perf_counter", lambda: now[0])
    monkeypatch.setattr(timing, "process_age", lambda: 2.0)
    timing.reset()
    yield now
    timing.reset()


def test_phases_add_up_nested_ones_pause_the_outer(clock):
    with timing.phase("steps"):
        clock[0] += 10
        with timing.phase("densify"):
            clock[0] += 3
        clock[0] += 5
    clock[0] += 1  # outside every phase
    with timing.phase("densify"):
        clock[0] += 2
    spent = timing.spent()
    assert spent == pytest.approx({"start-up": 2.0, "steps": 15.0, "densify": 5.0, "other": 1.0, "total": 23.0})


def test_summary_line_parses_back(clock):
    with timing.phase("read photos"):
        clock[0] += 0.25
    clock[0] += 0.5
    line = timing.summary()
    assert line == "timing: start-up 2.0 s, read photos 0.2 s, other 0.5 s; total 2.8 s"
    assert timing.parse(line) == pytest.approx({"start-up": 2.0, "read photos": 0.2, "other": 0.5, "total": 2.8})
    assert timing.parse("held-out views (1): PSNR 9.70 dB") is None


def test_no_phase_no_line(clock):
    assert timing.summary() is None and timing.spent() == {}


def test_process_age_is_this_process():
    assert 0 <= timing.process_age() < 3600


def test_a_step_part_is_a_plain_call_unless_a_timer_is_installed():
    from eve3d.core.timing import step_part, timing_step_parts

    @step_part("densify")
    def twice(x, by=2):
        return x * by

    seen = []

    def timer(part, fn, args, kwargs):
        seen.append((part, fn.__name__, args, kwargs))
        return fn(*args, **kwargs) + 1

    assert twice(3) == 6 and twice.__name__ == "twice"
    with timing_step_parts(timer):
        assert twice(3, by=3) == 10
    assert twice(3) == 6 and seen == [("densify", "twice", (3,), {"by": 3})]
