"""The benchmark's command as it writes its results (it asks git for the
commit): results taken under load are marked and not written unless asked
(tests/unit/test_bench_hygiene.py: the loads themselves)."""

from __future__ import annotations

from tests.bench import __main__ as bench
from tests.bench import hygiene


def _result(load: float) -> dict:
    figure = lambda seconds: hygiene.Figure([seconds] * 3, [load] * 3).as_dict()  # noqa: E731
    r = {
        "robots": 10,
        "runs": 3,
        "figures": {"noop": figure(1.5), "floor_exec_true": figure(1.2)},
        "load_at_start": [load],
        "load_at_end": [load],
        "noop_commands_per_host": 1,
    }
    from tests.bench.fleet import Bench

    Bench.ratios(r)
    return r


def test_results_taken_under_load_are_marked_and_not_written(monkeypatch, tmp_path):
    idle, loaded = _result(0.5), _result(3.0)
    assert "met**" in bench.markdown([idle], {}) and "Not every figure" not in bench.markdown([idle], {})
    text = bench.markdown([loaded], {})
    assert "Not every figure was taken on an idle machine" in text and "[load 3.0]" in text
    assert "met, loaded" in text
    monkeypatch.setattr(bench, "measure", lambda *a, **k: loaded)
    monkeypatch.setattr(bench, "HERE", tmp_path)
    assert bench.main(["--robots", "10", "--updates-at", "--fresh-at"]) == 1
    assert not (tmp_path / "RESULTS.md").exists()
    assert bench.main(["--robots", "10", "--updates-at", "--fresh-at", "--write-loaded"]) == 0
    assert "[load 3.0]" in (tmp_path / "RESULTS.md").read_text()
