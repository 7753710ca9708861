"""The shell script behind the snapshot (POSIX sh), built from what the
roles declared; ``snapshot.parse`` reads its output.  It changes nothing on
the host.

It runs on every host at every deploy, and in pull mode many times a day,
so it starts few programs, each asked once for everything:

- the declared probes start at once, in the background, under ONE
  ``timeout``, each into its own file of a temporary directory, while the
  rest is read; their outputs come back in one base64 blob (``stat`` gives
  the sizes that cut it apart);
- one ``stat`` and one ``sha256sum`` for all plain files, one
  ``systemctl show`` for all units (``is-enabled`` and ``is-active`` unit
  by unit where its answer does not come a block a unit), one ``groups``
  for all users, the package database read with ``awk`` (``dpkg-query``
  while dpkg's journal holds an unfinished run).

Where no temporary directory can be made, the probes run one after
another, each under its own timeout."""

from __future__ import annotations

import re
import shlex

# Seconds the probes together may take (docker, gpg, nvidia-smi, dpkg --audit
# run at once): a wedged dockerd must not hang the host's only snapshot
# command; a probe cut off reads as empty (unknown), as a failed one does.
PROBE_TIMEOUT = 60

DPKG_DIR = "/var/lib/dpkg"  # dpkg's database: its status file and journal (updates/)

# Paths that stat and sha256sum print as they are given (no escaping), read
# with one call of each; any other path gets its own tests and commands.
PLAIN_PATH = re.compile(r"/[A-Za-z0-9._@+:/-]*\Z")

T = "\t"


def _q(value: str) -> str:
    return shlex.quote(value)


def _os_release() -> list[str]:
    return [
        'l=; while IFS= read -r l || [ -n "$l" ]; do printf \'osl\\t%s\\n\' "$l"; l=; '
        "done 2>/dev/null < /etc/os-release",
        "printf 'arch\\t'; dpkg --print-architecture 2>/dev/null || echo",
    ]


def _files(files) -> list[str]:
    lines = []
    plain = [path for path in files if PLAIN_PATH.match(path)]
    if plain:
        names = " ".join(_q(p) for p in plain)
        lines.append(f"set -- {names}")
        lines.append('stat -c "stat$T%n$T%F$T%a %U %G" -- "$@" 2>/dev/null')
        # Keep the regular files (not links) of the list: each turn takes one off the front.
        lines.append('for p; do shift; [ -f "$p" ] && [ ! -L "$p" ] && set -- "$@" "$p"; done')
        lines.append('[ $# -gt 0 ] && sha256sum -- "$@" 2>/dev/null')
    for path in files:
        if path in plain:
            continue
        p = _q(path)
        lines.append(
            f'if [ -L {p} ]; then echo "file${{T}}"{p}"${{T}}link${{T}}-${{T}}$(stat -c \'%a %U %G\' {p})"; '
            f'elif [ -d {p} ]; then echo "file${{T}}"{p}"${{T}}dir${{T}}-${{T}}$(stat -c \'%a %U %G\' {p})"; '
            f'elif [ -f {p} ]; then echo "file${{T}}"{p}"${{T}}file${{T}}'
            f"$(sha256sum < {p} | cut -d' ' -f1)${{T}}$(stat -c '%a %U %G' {p})\"; "
            f'else echo "file${{T}}"{p}"${{T}}none"; fi'
        )
    return lines


def _users(users) -> list[str]:
    # One `groups` for all: a line "NAME : GROUP..." a user that exists (a
    # group with no name as its number), none for one that does not ("-").
    if not users:
        return []
    names = " ".join(_q(u) for u in users)
    return [
        f"g=$(groups -- {names} 2>/dev/null)",
        f"for u in {names}; do v=-; while IFS= read -r l; do case $l in",
        '  "$u : "*) v=${l#"$u : "}; break ;; "$u :") v=; break ;;',
        "esac; done <<EOF",
        "$g",
        "EOF",
        'printf \'user\\t%s\\t%s\\n\' "$u" "$v"; done',
    ]


def _packages(packages) -> list[str]:
    if not packages:
        return []
    names = " ".join(_q(p) for p in packages)
    query = f"dpkg-query -W -f='pkg\\t${{Package}}\\t${{Status}}\\t${{Version}}\\n' {names} 2>/dev/null"
    # dpkg-query's lines for these names, from dpkg's status file; while
    # dpkg's journal (updates/) holds an unfinished run, dpkg-query itself
    # (it reads the journal too).
    wanted = _q(" " + " ".join(packages) + " ")
    emit = 'if (index(w, " " p " ")) print "pkg\\t" p "\\t" s "\\t" v; p = s = v = ""'
    awk = (
        f"awk -v w={wanted} '/^Package: /{{p = substr($0, 10)}} /^Status: /{{s = substr($0, 9)}} "
        f"/^Version: /{{v = substr($0, 10)}} /^$/{{{emit}}} END{{{emit}}}' {_q(DPKG_DIR)}/status 2>/dev/null"
    )
    return [
        f'j=; for f in {_q(DPKG_DIR)}/updates/*; do [ -e "$f" ] && j=1; done',
        f'if [ -n "$j" ]; then {query}; else {awk}; fi',
    ]


def _units(units) -> list[str]:
    if not units:
        return []
    # One `systemctl show` for all (one program, one bus connection): a block
    # a unit, in the order asked, the two properties (-p shows them even
    # empty) in any order.  Where the blocks do not add up (no systemd to ask,
    # a name it refuses), each unit is asked alone with is-enabled/is-active.
    return [
        f"set -- {' '.join(_q(u) for u in units)}",
        's=$(systemctl show -p UnitFileState,ActiveState -- "$@" 2>/dev/null); o=; e=; a=; n=',
        "while IFS= read -r l; do case $l in",
        "  UnitFileState=*) e=${l#*=}; n=1 ;; ActiveState=*) a=${l#*=}; n=1 ;; *=*) ;;",
        '  "") [ $# -gt 0 ] && [ -n "$n" ] || { set -- x; break; }',
        '      o="${o}unit$T$1$T$e$T$a$NL"; shift; e=; a=; n= ;;',
        "  *) set -- x; break ;;",
        "esac; done <<EOF",
        "$s",
        "",
        "EOF",
        f'if [ $# -eq 0 ]; then printf %s "$o"; else for u in {" ".join(_q(u) for u in units)}; do',
        '  echo "unit$T$u$T$(systemctl is-enabled "$u" 2>/dev/null)$T$(systemctl is-active "$u" 2>/dev/null)"',
        "done; fi",
    ]


def _probes_program(probes: dict) -> str:
    """``sh -c "$I" sh DIR INDEX...``: the probes INDEX... at once, each
    into DIR/pINDEX (DIR/pINDEX.ok once it is done); with DIR empty, the
    one probe INDEX to stdout.  Each probe runs in a subshell with no
    arguments, as ``sh -c SNIPPET`` ran it: one process a probe, whose
    EXIT trap marks it done however it ends but killed (by the timeout);
    a probe that sets a trap of its own gets a subshell inside it."""
    arms = "".join(
        f"{index})\n{'( ' if 'trap' in snippet else ''}{snippet}{' )' if 'trap' in snippet else ''}\n;;\n"
        for index, snippet in enumerate(probes.values())
    )
    return (
        f"D=$1; shift\nrun() {{ i=$1; shift\ncase $i in\n{arms}esac; }}\n"
        'if [ -n "$D" ]; then\n'
        # The trap names its file when set: a probe may assign i or D.
        '  for i; do ( trap ": >\'$D/p$i.ok\'" EXIT; run $i >"$D/p$i" 2>/dev/null ) & done; wait\n'
        'else ( run "$1" ) 2>/dev/null; fi'
    )


def snapshot_script(files=(), packages=(), users=(), units=(), commands=(), probes=None) -> str:
    """The script (read-only, see the module)."""
    probes = dict(probes or {})
    lines = ["export LC_ALL=C", f"T='{T}'", "NL='\n'"]
    if probes:
        lines += [
            f"I={_q(_probes_program(probes))}",
            f"R={_q(' '.join(str(i) for i in range(len(probes))))}",
            "P=; if d=$(mktemp -d 2>/dev/null); then",
            "  trap 'rm -rf \"$d\"' EXIT",
            f'  timeout {PROBE_TIMEOUT} sh -c "$I" sh "$d" $R &',
            "  P=$!",
            "fi",
        ]
    lines += _os_release() + _files(files) + _packages(packages) + _users(users)
    lines += [f"printf 'cmd\\t%s\\t' {_q(c)}; command -v {_q(c)} || echo" for c in commands]
    lines += _units(units)
    if probes:
        lines += _probe_results()
    lines.append("true")
    return "\n".join(lines)


def _probe_results() -> list[str]:
    return [
        'if [ -n "$P" ]; then',
        '  wait "$P"; set --',
        '  for i in $R; do [ -e "$d/p$i.ok" ] && set -- "$@" "$d/p$i"; done',
        '  if [ $# -gt 0 ]; then stat -c "psize$T%n$T%s" -- "$@"; printf "pblob$T"',
        '    if [ $# -eq 1 ]; then base64 -w0 -- "$1"; else cat -- "$@" | base64 -w0; fi; echo',
        "  fi",
        "else",
        # No temporary directory: one after another, each under its own timeout.
        f"  for i in $R; do printf 'pone\\t%s\\t' $i; timeout {PROBE_TIMEOUT} sh -c \"$I\" sh '' $i | base64 -w0; "
        "echo; done",
        "fi",
    ]
