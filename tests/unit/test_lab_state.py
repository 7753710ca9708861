"""state.json round trip and its exact keys."""

import pytest

from tests.unit.samples import lab_state as sample


def test_round_trip(state, tmp_path):
    path = state.save(sample(), root=tmp_path)
    assert path == tmp_path / "t" / "state.json"
    assert state.load("t", root=tmp_path) == sample()


def test_keys_are_exactly_the_contract(state, tmp_path):
    with pytest.raises(ValueError):
        state.save(dict(sample(), extra=1), root=tmp_path)
    incomplete = sample()
    del incomplete["registry"]
    with pytest.raises(ValueError):
        state.save(incomplete, root=tmp_path)


def test_load_of_a_lab_that_is_not_up_says_how_to_start_it(state, tmp_path):
    from tests.lab.engine import LabError

    with pytest.raises(LabError, match="python3 -m tests.lab up --prefix nope"):
        state.load("nope", root=tmp_path)


def test_prefix_comes_from_the_environment(state, monkeypatch):
    monkeypatch.delenv("ROBOT_LAB_PREFIX", raising=False)
    assert state.lab_prefix() == "lab"
    monkeypatch.setenv("ROBOT_LAB_PREFIX", "e2e")
    assert state.lab_prefix() == "e2e"


def test_exec_output_is_what_came_before_the_end_mark_and_none_when_the_stream_lost_it():
    from tests.lab import state

    start = state.EXEC_START
    assert state.exec_output(start + "hi\nerr\n" + state.EXEC_MARK) == "hi\nerr\n"
    assert state.exec_output(start + "abc" + state.EXEC_MARK) == "abc"
    assert state.exec_output(start + state.EXEC_MARK) == ""
    assert state.exec_output("") is None  # docker exec lost the output: read the file again
    assert state.exec_output(start + "hi\n") is None
    got = state.exec_output(start + "a" + state.EXEC_MARK + "b" + state.EXEC_MARK)
    assert got == "a" + state.EXEC_MARK + "b"
    # the stream lost its start (a frame header came inside the text, under load): read the file again
    assert state.exec_output('",\n "x": 1\n}\n]\n\x01\x00\x00\x00\x00\x00\x00\x12' + state.EXEC_MARK) is None


def test_exec_argv_runs_the_command_itself_with_its_output_in_the_file():
    from tests.lab import state

    argv = state.exec_argv("echo 'a b'; exit 3", "/dev/shm/lab-exec-1")
    assert argv[:2] == ["sh", "-c"]
    assert argv[3:] == ["lab-exec", "/dev/shm/lab-exec-1", "sh", "-c", "echo 'a b'; exit 3"]
    assert state.exec_argv(["cat", "/etc/hostname"], "/o")[3:] == ["lab-exec", "/o", "cat", "/etc/hostname"]
