"""Shell completion and the manual page (issue 54, item 10), made by
`robotfleet completion` and `robotfleet man` from the commands' own
definitions, tried in the real programs: bash completes command lines from
the script (complete -p, then its function on the words bash gives it),
bash-completion loads what --install writes, zsh completes words typed in
an interactive shell (zpty), and man renders the page, groff without a
warning.  Every command of cli.COMMANDS is in each, by itself."""

from __future__ import annotations

import os
import re
import site
import subprocess
import sys
import venv
from pathlib import Path

import pytest

from robotfleet import cli
from tests.fixtures import ROOT

BASH_COMPLETION = Path("/usr/share/bash-completion/bash_completion")


def robotfleet(*argv: str, home: Path, python: str = sys.executable) -> subprocess.CompletedProcess:
    env = {"PATH": "/usr/bin:/bin", "HOME": str(home), "LANG": "C.UTF-8"}
    return subprocess.run(
        [python, "-m", "robotfleet", *argv], cwd=ROOT, capture_output=True, text=True, timeout=120, env=env
    )


def bash(script: str, cwd: Path) -> str:
    done = subprocess.run(
        ["bash", "--norc", "--noprofile", "-c", script],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=60,
        env={"PATH": "/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8"},
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


# Each line: complete it as bash would at its end (COMP_WORDS, COMP_CWORD), print what is offered.
COMPLETE = r"""
offer() {
    read -ra COMP_WORDS <<< "$1"
    [[ $1 == *" " ]] && COMP_WORDS+=("")
    COMP_CWORD=$(( ${#COMP_WORDS[@]} - 1 )) COMP_LINE=$1 COMP_POINT=${#1}
    COMPREPLY=()
    "$function" robotfleet "${COMP_WORDS[COMP_CWORD]}" "${COMP_WORDS[COMP_CWORD-1]}"
    echo "$1=>${COMPREPLY[*]}"
}
function=$(complete -p robotfleet | sed -E 's/.* -F ([^ ]+) .*/\1/')
"""

LINES = {
    "robotfleet ": set(cli.COMMANDS),
    "robotfleet sta": {"status"},
    "robotfleet status --for": {"--format"},
    "robotfleet status --format ": {"table", "wide", "json", "openmetrics"},
    "robotfleet status -o w": {"wide"},
    "robotfleet keys ": {"init", "show", "rotate", "prepare", "sign", "install", "generate"},
    "robotfleet keys rotate ": {"online", "root"},
    "robotfleet publish --leave": {"--leave-out-uncommitted"},
    "robotfleet publish --allow": set(),  # the old name works, but is not offered
    "robotfleet completion ": {"bash", "zsh"},
    "robotfleet enroll --fingerprints fing": {"fingerprints.txt"},
    "robotfleet export medi": {"media"},  # a directory (shown with its /), not the file medium.txt
}


def test_bash_completes_commands_options_choices_and_files(tmp_path):
    made = robotfleet("completion", "bash", home=tmp_path)
    assert made.returncode == 0, made.stderr
    (tmp_path / "robotfleet.bash").write_text(made.stdout)
    (tmp_path / "fingerprints.txt").write_text("")
    (tmp_path / "media").mkdir()
    (tmp_path / "medium.txt").write_text("")
    lines = "\n".join(f"offer {line!r}" for line in LINES)
    said = bash(f". ./robotfleet.bash\ncomplete -p robotfleet\n{COMPLETE}\n{lines}", tmp_path).splitlines()
    assert re.fullmatch(r"complete .*-F \w+ robotfleet", said[0]), said[0]
    offered = dict(line.split("=>", 1) for line in said[1:])
    for line, expected in LINES.items():
        assert set(offered[line].split()) == expected, (line, offered[line])


def test_install_is_what_bash_completion_loads_and_replaces_only_its_own(tmp_path):
    done = robotfleet("completion", "bash", "--install", home=tmp_path)
    path = tmp_path / ".local/share/bash-completion/completions/robotfleet"
    assert done.returncode == 0 and done.stdout.startswith(f"completion: {path}: "), done.stderr
    if BASH_COMPLETION.exists() or os.environ.get("CI"):  # .ci/setup installs it
        loaded = bash(f". {BASH_COMPLETION}\n__load_completion robotfleet\ncomplete -p robotfleet", tmp_path)
        assert re.fullmatch(r"complete .*-F \w+ robotfleet\n", loaded), loaded
    assert robotfleet("completion", "bash", "--install", home=tmp_path).returncode == 0  # its own: replaced
    path.write_text("# someone's own\n")
    refused = robotfleet("completion", "bash", "--install", home=tmp_path)
    assert (refused.returncode, refused.stderr) == (
        2,
        f"completion: {path}: there already, and not written by robotfleet; left as it is\n",
    )
    assert path.read_text() == "# someone's own\n"


ZSH = r"""
zmodload zsh/zpty
zpty -b z 'zsh -f -i'
zpty -w z 'PS1="" PROMPT_EOL_MARK=""; fpath=(FUNCTIONS $fpath); autoload -Uz compinit; compinit -u -D'
zpty -w z 'print READY'
zpty -r -m z out '*READY*'
for typed in 'robotfleet compl' 'robotfleet status --for' 'robotfleet keys rot'; do
  zpty -w -n z "$typed"$'\t'
  sleep 1
  zpty -w -n z $'\x15'  # ^U: the line killed in the line editor (^C's signal could overtake what follows)
done
zpty -w z 'print DONE'
zpty -r -m z out '*DONE*'
print -r -- "$out"
zpty -d z
"""


def test_zsh_completes_words_typed_in_an_interactive_shell(tmp_path):
    done = robotfleet("completion", "zsh", "--install", home=tmp_path)
    path = tmp_path / ".local/share/zsh/site-functions/_robotfleet"
    assert done.returncode == 0 and f"fpath=({path.parent} $fpath)" in done.stdout, done.stdout + done.stderr
    assert path.read_text().startswith("#compdef robotfleet\n# robotfleet's completion for zsh")
    typed = subprocess.run(
        ["zsh", "-f", "-c", ZSH.replace("FUNCTIONS", str(path.parent))],
        capture_output=True,
        text=True,
        timeout=60,
        env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "LANG": "C.UTF-8", "TERM": "dumb"},
    )
    shown = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]|[\x08\r]", "", typed.stdout)
    for completed in ("robotfleet completion ", "robotfleet status --format ", "robotfleet keys rotate "):
        assert completed in shown, (completed, typed.stdout, typed.stderr)


@pytest.fixture(scope="module")
def environment(tmp_path_factory) -> Path:
    """A virtual environment of its own for man --install to write into (the
    test runner's dependencies through a .pth; robotfleet from the checkout)."""
    env = tmp_path_factory.mktemp("venv") / "venv"
    venv.create(env, with_pip=False)
    python = env / "bin" / "python"
    purelib = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], capture_output=True, text=True
    ).stdout.strip()
    Path(purelib, "deps-of-the-test-runner.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    return env


def test_the_manual_page_renders_and_man_finds_it_installed(tmp_path, environment):
    made = robotfleet("man", home=tmp_path)
    assert made.returncode == 0, made.stderr
    page = tmp_path / "robotfleet.1"
    page.write_text(made.stdout)
    warned = subprocess.run(["groff", "-man", "-Tutf8", "-ww", "-z", page], capture_output=True, text=True)
    assert (warned.returncode, warned.stderr) == (0, "")
    shown = subprocess.run(
        ["man", "-l", page], capture_output=True, text=True, env={"PATH": "/usr/bin:/bin", "MANWIDTH": "100"}
    )
    assert shown.returncode == 0 and shown.stderr == "", shown.stderr
    text = re.sub(r".\x08", "", shown.stdout)
    assert text.startswith("ROBOTFLEET(1)")
    for name in cli.COMMANDS:
        assert f"\n   robotfleet {name}\n" in text, name
    assert "--leave-out-uncommitted" in text and "--allow-dirty" not in text
    assert "robotfleet keys rotate" in text and "{online,root}" in text

    done = robotfleet("man", "--install", home=tmp_path, python=str(environment / "bin" / "python"))
    installed = environment / "share/man/man1/robotfleet.1"
    assert done.returncode == 0 and done.stdout.startswith(f"man: {installed}: "), done.stdout + done.stderr
    found = subprocess.run(
        ["man", "-w", "robotfleet"],
        capture_output=True,
        text=True,
        env={"PATH": f"{environment / 'bin'}:/usr/bin:/bin", "HOME": str(tmp_path)},
    )
    assert found.stdout.strip() == str(installed), found.stderr
