"""Every setting the fleet file may hold, from the declarations of the
engine and of the roles, and the checks built on them: one layer of data (a
host, a group's vars), a host's merged data, the data pyinfra ends up with.

Checks are pure, so they run before any host is contacted."""

from __future__ import annotations

from collections.abc import Iterable

from robotfleet import checkers as c
from robotfleet.role import UNSET, Renamed, Role, Setting


class Registry:
    def __init__(
        self,
        settings: Iterable[Setting],
        roles: Iterable[Role] = (),
        aliases: dict[str, str] | None = None,
        rules: Iterable = (),
        renamed: Iterable[Renamed] = (),
    ):
        """``settings``, ``rules`` and ``renamed``: the engine's own, beside each role's."""
        self.roles = tuple(roles)
        self.aliases = dict(aliases or {})
        self.rules = (*(role.rules for role in self.roles), *rules)  # the engine's after the roles'
        self.settings: dict[str, Setting] = {}
        for setting in [*settings, *(s for role in self.roles for s in role.settings)]:
            if setting.name in self.settings:
                raise ValueError(f"setting {setting.name} is declared twice")
            self.settings[setting.name] = setting
        self.mergers = [(name, s.merge) for name, s in self.settings.items() if s.merge is not None]
        # A setting's older name -> its rename (the engine's and each role's ``renamed``).
        self.renamed: dict[str, Renamed] = {}
        for rename in (*renamed, *(r for role in self.roles for r in role.renamed)):
            if rename.new not in self.settings or rename.old in self.settings or rename.old in self.renamed:
                raise ValueError(
                    f"rename {rename.old} -> {rename.new}: the old name must be free and the new one declared"
                )
            self.renamed[rename.old] = rename

    def name_of(self, key: str) -> str:
        """The setting ``key`` sets: itself, or what its alias or old name stands for."""
        rename = self.renamed.get(key)
        return rename.new if rename is not None else self.aliases.get(key, key)

    def old_check(self, rename: Renamed) -> c.Checker:
        """What the old name accepts: its own values, or the new one's."""
        return c.string(choices=tuple(rename.values)) if rename.values else self.settings[rename.new].check

    @staticmethod
    def renamed_value(rename: Renamed, value):
        """An old name's value as the new name's."""
        return rename.values.get(value, value) if rename.values and isinstance(value, str) else value

    def defaults(self, group: str | None = None) -> dict:
        """The defaults of every setting for hosts of ``group`` (None: all)."""
        result = {}
        for name, setting in self.settings.items():
            value = setting.default_in(group)
            if value is not UNSET:
                result[name] = value
        return result

    def group_defaults(self, group: str) -> dict:
        """Only what differs in ``group`` from the defaults of all hosts."""
        return {s.name: s.default_in(group) for s in self.settings.values() if group in s.groups}

    def merge(self, layers: list[dict]) -> dict:
        """all.vars < group vars < host: the last layer that sets a setting
        wins, except where the setting says how its layers combine."""
        merged: dict = {}
        for layer in layers:
            merged.update(layer)
        for name, merge in self.mergers:
            values = [layer[name] for layer in layers if name in layer]
            if len(values) > 1:
                merged[name] = merge(values)
        return merged

    def check_layer(self, data: dict) -> list[c.Problem]:
        """Problems in one layer of data (a host, a group's vars): keys and types."""
        problems = []
        for key, value in data.items():
            if not isinstance(key, str):
                problems.append((c.key_name(key), f"a setting name must be a string, got {c.describe(key)}; quote it"))
                continue
            rename = self.renamed.get(key)
            setting = self.settings.get(self.aliases.get(key, key))
            if rename is not None:
                problems += [(f"{key}{sub}", msg) for sub, msg in self.old_check(rename)(value)]
                continue
            if setting is None:
                known = list(self.settings) + list(self.aliases)
                problems.append((c.key_name(key), "unknown setting" + c.did_you_mean(key, known)))
                continue
            problems += [(f"{key}{sub}", msg) for sub, msg in setting.check(value)]
        return problems

    def check_host(self, data: dict, refused=frozenset()) -> list[c.Problem]:
        """Rules across settings, on a host's merged data (defaults and every
        layer).  A setting in ``refused`` already has a problem: no rule
        looks at it again."""
        refused = frozenset(refused)
        return [problem for rule in self.rules for problem in rule(data, refused)]

    def data_problems(self, data) -> list[str]:
        """Problems in a host's final data (pyinfra host.data, including
        --data overrides, which never went through the fleet file), as
        'field: message'."""
        missing = object()
        values = {}
        for key in self.settings:
            value = data.get(key, missing)
            if value is not missing:
                values[key] = value
        layer = self.check_layer(values)
        problems = layer + self.check_host(values, {setting_of(field) for field, _ in layer})
        return [f"{field}: {message}" for field, message in problems]


def setting_of(field: str) -> str:
    """The setting a problem's field belongs to: udev_sensors[1].serial -> udev_sensors."""
    return field.split(".")[0].split("[")[0]
