"""The benchmark's hygiene: loads recorded and shown (the command that refuses
loaded results: tests/integration/test_bench_hygiene.py)."""

from __future__ import annotations

from tests.bench import hygiene


def test_a_figure_is_idle_only_if_every_sample_started_below_the_limit():
    figure = hygiene.Figure()
    figure.add(2.0, 0.4)
    figure.add(1.0, 1.2)
    figure.add(3.0, 0.9)
    assert figure.median == 2.0 and figure.idle
    assert hygiene.shown(figure.as_dict()) == "2.00 (1.00–3.00)"
    figure.add(9.0, 3.4)
    assert not figure.idle
    assert hygiene.shown(figure.as_dict()) == "2.50 (1.00–9.00) [load 3.4]"


def test_waiting_for_idle_returns_the_load_it_started_at(monkeypatch):
    readings = iter([4.0, 2.0, 1.1])
    monkeypatch.setattr(hygiene, "load", lambda: next(readings))
    monkeypatch.setattr(hygiene.time, "sleep", lambda seconds: None)
    assert hygiene.wait_for_idle("x", patience=60) == 1.1
    monkeypatch.setattr(hygiene, "load", lambda: 5.0)
    assert hygiene.wait_for_idle("x", patience=0) == 5.0


def test_a_figure_s_later_samples_wait_for_a_quiet_machine_not_for_the_load_average(monkeypatch):
    """The load average still counts the figure's own first sample; what is
    running now decides the later ones, and a busy machine marks them."""
    monkeypatch.setattr(hygiene.time, "sleep", lambda seconds: None)
    monkeypatch.setattr(hygiene, "load", lambda: 2.7)
    busy = iter([1.6, 0.2])
    monkeypatch.setattr(hygiene, "busy_cores", lambda: next(busy))
    assert hygiene.wait("x", first=False, patience=60) == (2.7, True)
    assert hygiene.wait("x", first=True, patience=0) == (2.7, False)  # the first sample needs the load below 1.5
    monkeypatch.setattr(hygiene, "busy_cores", lambda: 1.9)
    assert hygiene.wait_for_quiet("x", patience=0) == (2.7, False)
    figure = hygiene.Figure()
    figure.add(1.0, 1.0)
    figure.add(1.2, 2.7, True)
    figure.add(1.1, 2.4, True)
    assert figure.idle and hygiene.shown(figure.as_dict()) == "1.10 (1.00–1.20)"
    figure.add(5.0, 2.1, False)
    assert not figure.idle


def test_busy_cores_reads_the_machine():
    assert 0.0 <= hygiene.busy_cores(0.2) <= (__import__("os").cpu_count() or 1)
