"""Scenarios by versioned name (``case-a-payload-v1``); a name without a version means the latest."""

from __future__ import annotations

import re

from ..errors import ScenarioError
from .spec import ScenarioSpec

_VERSIONED = re.compile(r"^(?P<base>.+)-v(?P<ver>\d+)$")


class Registry:
    """A name -> spec table. The package keeps one default instance, filled at import with the paper's cases."""

    def __init__(self) -> None:
        self._specs: dict[str, ScenarioSpec] = {}

    def register(self, spec: ScenarioSpec) -> None:
        if not _VERSIONED.match(spec.name):
            raise ScenarioError(f"scenario names carry a version suffix like '-v1', got {spec.name!r}")
        if spec.name in self._specs:
            raise ScenarioError(f"scenario {spec.name!r} is already registered")
        self._specs[spec.name] = spec

    def names(self, latest_only: bool = False) -> list[str]:
        if not latest_only:
            return sorted(self._specs)
        latest: dict[str, tuple[int, str]] = {}
        for n in self._specs:
            m = _VERSIONED.match(n)
            assert m is not None
            b, v = m["base"], int(m["ver"])
            if b not in latest or v > latest[b][0]:
                latest[b] = (v, n)
        return sorted(n for _, n in latest.values())

    def resolve(self, name: str) -> str:
        if name in self._specs:
            return name
        versions = [n for n in self._specs if (m := _VERSIONED.match(n)) and m["base"] == name]
        if versions:
            return max(versions, key=lambda n: int(_VERSIONED.match(n)["ver"]))  # type: ignore[index]
        raise ScenarioError(
            f"unknown scenario {name!r}; valid scenarios: "
            + ", ".join(self.names(latest_only=True))
            + " (a name without '-vN' means the latest version)"
        )

    def get(self, name: str) -> ScenarioSpec:
        return self._specs[self.resolve(name)]


DEFAULT = Registry()


def register(spec: ScenarioSpec) -> None:
    DEFAULT.register(spec)


def get(name: str) -> ScenarioSpec:
    return DEFAULT.get(name)


def names(latest_only: bool = True) -> list[str]:
    return DEFAULT.names(latest_only)
