"""Scenarios by versioned name (``case-a-payload-v1``); a name without a version means the latest."""

from __future__ import annotations

import re

from ..errors import ScenarioError, instance
from .spec import ScenarioSpec

_VERSIONED = re.compile(r"^(?P<base>.+)-v(?P<ver>\d+)$")


class Registry:
    """A name -> spec table. The package keeps one default instance, filled at import with the paper's cases."""

    def __init__(self) -> None:
        self._specs: dict[str, ScenarioSpec] = {}

    def register(self, spec: ScenarioSpec) -> None:
        """Add ``spec`` under its name, which must end in a version (``-v1``) and be new."""
        if not _VERSIONED.match(spec.name):
            raise ScenarioError(f"scenario names carry a version suffix like '-v1', got {spec.name!r}")
        if spec.name in self._specs:
            raise ScenarioError(f"scenario {spec.name!r} is already registered")
        self._specs[spec.name] = spec

    def names(self, latest_only: bool = False) -> list[str]:
        """Registered names, sorted; with ``latest_only`` only the latest version of each scenario."""
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
        """The registered name ``name`` refers to: itself, or the latest version of a name without one.
        Raises :class:`~vtol_impedance.errors.ScenarioError` listing the valid names."""
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
        """The scenario ``name`` (see :meth:`resolve`)."""
        return self._specs[self.resolve(name)]


#: The package's registry: the paper's cases and the interaction scenarios, registered at import.
DEFAULT = Registry()


def register(spec: ScenarioSpec) -> None:
    """Register ``spec`` in :data:`DEFAULT`, so that ``get``, the CLI and sweeps know it by name."""
    instance("spec", spec, ScenarioSpec)
    DEFAULT.register(spec)


def get(name: str) -> ScenarioSpec:
    """The registered scenario ``name``: ``"case-a-payload-v1"``, or ``"case-a-payload"`` for the latest
    version. Raises :class:`~vtol_impedance.errors.ScenarioError` naming the valid scenarios."""
    if not isinstance(name, str):
        raise ScenarioError(f"unknown scenario {name!r}: name must be the str name of a registered scenario")
    return DEFAULT.get(name)


def names(latest_only: bool = True) -> list[str]:
    """Registered scenario names, sorted; by default only the latest version of each."""
    return DEFAULT.names(latest_only)
