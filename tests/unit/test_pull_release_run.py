"""What the agent reads from a release's converge and from a role's
prepared switch: the last line that is a JSON object, whatever else they
printed (pyinfra's output, a line cut short by a full disk)."""

from robotfleet.pull.robot import release_run


def test_the_last_json_object_line_is_the_answer():
    text = 'pyinfra says\n{"outcome": "first"}\n--> done\n{"outcome": "applied"}\n'
    assert release_run.last_json(text) == {"outcome": "applied"}


def test_a_line_that_is_not_a_whole_object_is_passed_over():
    text = '{"outcome": "applied"}\n{"outcome": "cut sh\n{not json}\n'
    assert release_run.last_json(text) == {"outcome": "applied"}
    assert release_run.last_json('{"a": 1}\n["a", "list"]\n') == {"a": 1}  # "[" is no answer


def test_nothing_readable_is_none():
    assert release_run.last_json("") is None
    assert release_run.last_json("Traceback (most recent call last):\n{broken\n") is None
