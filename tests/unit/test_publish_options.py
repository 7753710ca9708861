"""publish's rollout options are named as the operator typed them (issue 39
item 9): a bad --waves is "--waves 50%,40%: its share 2: ...", not the
release record's field "options.waves[1]"."""

from __future__ import annotations

import pytest

from robotfleet.commands.pull import publish


@pytest.mark.parametrize(
    "argv, said",
    [
        (
            ["--waves", "50%,40%"],
            "--waves 50%,40%: its share 2: shares are cumulative and must rise, got 40% after 50%; "
            "nothing was published",
        ),
        (["--waves", "50%"], "--waves 50%: the last wave must be 100% (every robot), got 50%; nothing was published"),
        (
            ["--canary", "many"],
            "--canary many: expected a number of robots or a percentage like 25%, got 'many'; nothing was published",
        ),
        (["--max-failed", "-1"], "--max-failed -1: "),
    ],
)
def test_a_bad_rollout_option_is_named_as_given(argv, said):
    with pytest.raises(ValueError) as raised:
        publish.plan_of(publish.parse_args(argv))
    assert str(raised.value).startswith(said) and "options." not in str(raised.value)


def test_good_options_make_the_plan():
    plan = publish.plan_of(publish.parse_args(["--canary", "10%", "--waves", "50%,100%", "--pause", "60"]))
    assert (str(plan.canary), [str(w) for w in plan.waves], plan.pause) == ("10%", ["50%", "100%"], 60)
