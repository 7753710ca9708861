"""The release's converge module run as the agent runs it (release_run.run):
its answer read from what it printed."""

import sys

from robotfleet.pull.robot import release_run


def test_a_converge_whose_last_line_is_cut_short_is_read_not_raised(tmp_path):
    """The release's converge module run as the agent runs it, printing its
    answer and then a line a full disk cut short."""
    module = tmp_path / "robotfleet" / "commands"
    module.mkdir(parents=True)
    for package in (tmp_path / "robotfleet", module):
        (package / "__init__.py").write_text("")
    (module / "converge.py").write_text('print(\'{"outcome": "applied"}\')\nprint(\'{"outcome": "cut\')\n')
    assert release_run.run(sys.executable, tmp_path, []) == {"outcome": "applied"}
    (module / "converge.py").write_text("import sys\nsys.exit('no answer')\n")
    assert release_run.run(sys.executable, tmp_path, []) == {"error": "converge said nothing (no answer)"}
