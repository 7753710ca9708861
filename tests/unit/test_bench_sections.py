"""RESULTS.md's sections written by the pull and stops benchmarks: set in
place, appended, kept when `python3 -m tests.bench` rewrites its own part;
and the two sections' tables (pure)."""

from tests.bench import pull, sections, stops

MAIN = "# Fleet benchmark results\n\n## Figures\n\n| a | b |\n"


def test_a_section_is_appended_then_replaced_in_place():
    once = sections.replace(MAIN, "pull", "## Pull mode\n\nfirst\n")
    assert once.startswith(MAIN) and sections.begin("pull") in once and "first" in once
    both = sections.replace(once, "stops", "## Stops\n\nx\n")
    again = sections.replace(both, "pull", "## Pull mode\n\nsecond\n")
    assert "first" not in again and "second" in again
    assert again.index("second") < again.index("## Stops"), "replaced where it was, not moved"
    assert again.count(sections.begin("pull")) == 1 and again.count(sections.end("pull")) == 1


def test_the_main_benchmark_keeps_the_other_sections(tmp_path):
    path = tmp_path / "RESULTS.md"
    path.write_text(sections.replace(sections.replace("# old main part\n", "pull", "P\n"), "stops", "S\n"))
    written = sections.rewrite_main("# new main part\n", path)
    assert written.startswith("# new main part\n") and "# old main part" not in written
    assert written.index("P\n") < written.index("S\n")
    assert sections.kept(written) == sections.kept(path.read_text())
    assert sections.rewrite_main("# new\n", tmp_path / "absent.md") == "# new\n"


def test_write_sets_the_section_and_its_data_file(tmp_path):
    path = tmp_path / "RESULTS.md"
    path.write_text(MAIN)
    sections.write("pull", "## Pull mode\n\nbody\n", {"figures": 1}, path)
    assert "body" in path.read_text() and path.read_text().startswith(MAIN)
    assert (tmp_path / "RESULTS-pull.json").read_text().strip() == '{\n  "figures": 1\n}'


def sample(to50, to100, idle=True):
    return {
        "interval": 30,
        "jitter": 15,
        "robots": 10,
        "reached": 10 if to100 else 7,
        "to_50%": to50,
        "to_100%": to100,
        "bytes_per_update": 20_000,
        "load": 0.4 if idle else 2.1,
        "idle": idle,
    }


def test_rollout_samples_give_median_and_spread_or_none_when_one_never_got_there():
    figure = pull.rollout_figure([sample(10.0, 40.0), sample(12.0, 30.0), sample(11.0, 50.0)])
    assert figure["to_50%"] == {"median": 11.0, "min": 10.0, "max": 12.0}
    assert figure["to_100%"]["median"] == 40.0 and figure["idle"] and figure["reached"] == 10
    short = pull.rollout_figure([sample(10.0, 40.0), sample(12.0, None)])
    assert short["to_100%"] is None and short["reached"] == 7


def test_the_pull_section_marks_a_figure_taken_under_load():
    idle = {
        "seconds": 0.9,
        "cpu": 0.2,
        "cpu_min": 0.18,
        "cpu_max": 0.25,
        "sent": 4000,
        "received": 5000,
        "requests": 1,
        "samples": 5,
        "idle": True,
        "load": 0.3,
    }
    figures = {
        "robots": 10,
        "idle_check": {"without a report push": idle},
        "rollouts": [pull.rollout_figure([sample(10.0, 40.0, idle=False)])],
        "fleet_per_hour": [pull.fleet_per_hour({"without a report push": idle}, 900, 300)],
    }
    text = pull.markdown(figures, {"commit": "abc"})
    assert "| 30 s / 15 s | 10.0 (10.0–10.0) | 40.0 (40.0–40.0) [load 2.1] | 20,000 | 1 |" in text
    assert "| without a report push | 0.90 | 0.20 (0.18–0.25) | 4,000 | 5,000 | 1 | 5 |" in text
    assert "10,000-robot fleet" in text and "Formula: checks = " in text
    assert not pull.all_idle(figures)


def test_the_stops_section_shows_the_settings_but_not_the_command():
    row = {
        "kind": "sigint-only",
        "payload": "stops on SIGINT only",
        "settings_label": "with the settings",
        "settings": {"payload_command": ["/bin/sh"], "ros_preset": "ros2"},
        "update": 5.2,
        "stop": 0.11,
        "down": 0.2,
        "rest": 5.09,
        "stop_min": 0.1,
        "stop_max": 0.12,
        "samples": 4,
        "exits": [0],
        "idle": True,
        "load": 0.2,
    }
    text = stops.markdown([row], {"robot": "robot1"})
    assert '| stops on SIGINT only | with the settings: `ros_preset: "ros2"` | 5.20 | 0.11 (0.10–0.12) | 0.20 |' in text
    assert "/bin/sh" not in text
